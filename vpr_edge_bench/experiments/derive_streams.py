"""Write the query streams a vehicle produces, derived from a frame-aligned dataset pair, with ground truth.

    python -m vpr_edge_bench derive-streams --dataset ../shared/datasets/nordland-dev --out out/nordland-dev

DATASET holds ref/ and query/ whose i-th files show the same place. OUT gets ref/ (the first --map-places
references: the map's places), and per stream kind (aligned, speed2, speed3, stop-and-go, variable, partial,
detour, camera-stops) a folder of frames OUT/KIND/ and its ground truth OUT/KIND.csv (true place, empty =
unmapped). Frames are hard links to the dataset's files where the file system allows. camera-stops stops where
stop-and-go does, but each repeat is a new exposure as a real camera makes it (sensor noise, gain, sub-pixel
vibration: ``streams.CAMERA``); with --repeat-noise S every other kind's repeats are noisy PNG copies too
(sensor noise of S grey levels). Then, for instance:

    vpr-edge build-map OUT/ref --out OUT/map.npz
    vpr-edge evaluate --map OUT/map.npz --queries OUT/speed2 --gt OUT/speed2.csv

With --drives N the map's places are also cut into N drives, OUT/drives/0 .. N-1, whose frames share names
(frame_0000.jpg ... in each), with ground truth naming places DRIVE/NAME (OUT/drives/KIND.csv); the drives are
printed in a shuffled order, as a fleet's come in (``streams.cut_into_drives``):

    vpr-edge build-map OUT/drives/2 OUT/drives/0 OUT/drives/3 OUT/drives/1 --out OUT/drives.npz
    vpr-edge evaluate --map OUT/drives.npz --queries OUT/speed2 --gt OUT/drives/speed2.csv
"""
from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from vpr_edge_bench.runner import parser, run_checked
from vpr_edge_bench.streams import KINDS, derive_streams, drive_order


def main(argv: Sequence[str] | None = None) -> int:
    p = parser(__name__, __doc__)
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
    p.add_argument("--drives", type=int, default=0, help="also cut the map into this many drives (OUT/drives/)")
    a = p.parse_args(argv)
    return run_checked(__name__, lambda: _run(a))


def _run(a: argparse.Namespace) -> int:
    """The work of ``main`` (``streams.derive_streams``: inputs checked first)."""
    counts = derive_streams(a.dataset, a.out, a.kinds.split(","), a.map_places, a.seed, a.repeat_noise, a.drives)
    n_mapped = counts.pop("map places")
    for kind, frames in counts.items():
        print(f"{kind:12s} {frames:6d} frames")
    print(f"map places: {n_mapped} (folder {a.out / 'ref'})")
    if a.drives:
        print("drives, shuffled:", " ".join(drive_order(a.out, a.drives, a.seed)))
    return 0

