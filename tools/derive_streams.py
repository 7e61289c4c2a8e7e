#!/usr/bin/env python3
"""Write the query streams a vehicle produces, derived from a frame-aligned dataset pair, with ground truth.

    python tools/derive_streams.py --dataset ../shared/datasets/nordland-dev --out out/nordland-dev

DATASET holds ref/ and query/ whose i-th files show the same place. OUT gets ref/ (the first --map-places
references: the map's places), and per stream kind (aligned, speed2, speed3, stop-and-go, variable, partial,
detour, camera-stops) a folder of frames OUT/KIND/ and its ground truth OUT/KIND.csv (true place, empty =
unmapped). Frames are hard links to the dataset's files where the file system allows. camera-stops stops where
stop-and-go does, but each repeat is a new exposure as a real camera makes it (sensor noise, gain, sub-pixel
vibration: ``streams.CAMERA``); with --repeat-noise S every other kind's repeats are noisy PNG copies too
(sensor noise of S grey levels). Then, for instance:

    vpr-edge build-map OUT/ref --out OUT/map.npz
    vpr-edge evaluate --map OUT/map.npz --queries OUT/speed2 --gt OUT/speed2.csv
"""
from __future__ import annotations

import argparse
from pathlib import Path


import numpy as np

from vpr_edge.errors import VprError, one_line_errors
from vpr_edge.frames.images import list_images
from vpr_edge.evaluation.streams import CAMERA, KINDS, derive_stream, write_stream


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--dataset", type=Path, required=True)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--map-places", type=int, default=None,
                   help="places in the map (default: two thirds of the references; the rest are detour places)")
    p.add_argument("--kinds", default=",".join(KINDS))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--repeat-noise", type=float, default=0.0,
                   help="sigma (grey levels) of Gaussian sensor noise on a frame that repeats the one before "
                        "(stops, slow crawls), so that a stopped vehicle's frames are alike but not identical "
                        "(default 0: the same file again)")
    a = p.parse_args()
    return one_line_errors("derive_streams", lambda: _run(a))


def _run(a: argparse.Namespace) -> int:
    """The work of ``main``, inputs checked first: the pair's folders, --map-places, --kinds, --repeat-noise."""
    refs, queries = list_images(a.dataset / "ref"), list_images(a.dataset / "query")
    if len(refs) != len(queries):
        raise VprError(f"{a.dataset}: ref/ and query/ differ in length ({len(refs)} vs {len(queries)})")
    n_mapped = a.map_places or (2 * len(refs)) // 3
    if not 0 < n_mapped <= len(refs):
        raise VprError(f"--map-places must be in 1..{len(refs)}")
    kinds = a.kinds.split(",")
    unknown = [k for k in kinds if k not in KINDS]
    if unknown:
        raise VprError(f"--kinds: unknown {', '.join(unknown)}; choose from {', '.join(KINDS)}")
    if a.repeat_noise < 0:
        raise VprError(f"--repeat-noise must be >= 0, got {a.repeat_noise}")
    write_stream(a.out / "ref", refs, np.arange(n_mapped), n_mapped, with_truth=False)
    for kind in kinds:
        places = derive_stream(kind, n_mapped, len(refs), a.seed)
        write_stream(a.out / kind, queries, places, n_mapped, repeat_noise=a.repeat_noise, seed=a.seed,
                     exposure=CAMERA if kind == "camera-stops" else None)
        print(f"{kind:12s} {len(places):6d} frames, {int((places >= n_mapped).sum()):5d} of unmapped places")
    print(f"map places: {n_mapped} of {len(refs)} (folder {a.out / 'ref'})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
