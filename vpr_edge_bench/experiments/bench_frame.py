"""Per-frame latency of the on-vehicle path, stage by stage, on real frames (batch size 1).

    python -m vpr_edge_bench bench-frame [--map MAP] [--frames DIR] [--threads 1,2] [--blas held|default]
                                         [--standardise off|on|both]

The chain timed is ``Localizer``'s own (``push`` = ``encode`` + ``push_encoding``), split into its stages:
decode (image file -> RGB), features (the front end: resize, normalise, ONNX tap), encode (the map's
encoder, IFV by default), match (``push_encoding``: the motion cue, the similarities the matcher asks for,
its update and the output line). Without --map, one is built from the bundled sample's references with
build-map's defaults (``write_map``; not timed). --blas held (default) limits NumPy's BLAS pool to the same
thread count as onnxruntime (what --threads does in the CLI); --blas default leaves BLAS at its own default
(one thread per core), for comparison; run the two in separate processes, since the limit is process-wide.
--standardise on times the chain with standardised encodings (``encoders.standardise``, localize's
--standardise); both times plain and standardised Localizers side by side, pass by pass, the order turned
each pass, and prints their ratio, each one's peak memory allocated while matching a pass (tracemalloc,
an untimed pass of ``push_encoding`` on the pass's encodings) and the process's peak RSS (both Localizers).
"""
from __future__ import annotations

import tempfile
import tracemalloc
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vpr_edge import Localizer
from vpr_edge.frames.images import list_images, load_image
from vpr_edge.map.make import BuildOptions, plan_map, write_map
from vpr_edge.profiling.stages import peak_rss_mb, time_stages
from vpr_edge.resources import sample_folder
from vpr_edge_bench.runner import parser


def main(argv: Sequence[str] | None = None) -> int:
    p = parser(__name__, __doc__)
    p.add_argument("--map", type=Path, default=None)
    p.add_argument("--model", type=Path, default=None)
    p.add_argument("--frames", type=Path, default=sample_folder() / "query")
    p.add_argument("--threads", default="1,2", help="onnxruntime thread counts to try")
    p.add_argument("--matcher", default="stream", help="registered online matcher")
    p.add_argument("--repeat", type=int, default=2, help="passes over the frames (the first is warm-up)")
    p.add_argument("--blas", choices=("held", "default"), default="held")
    p.add_argument("--standardise", choices=("off", "on", "both"), default="off",
                   help="standardised encodings (localize --standardise): off, on, or both side by side")
    a = p.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="vpr-edge-bench-") as tmp:
        map_path = a.map
        if map_path is None:   # the bundled sample's map, as build-map makes it
            map_path = Path(tmp) / "sample.map.npz"
            write_map(plan_map(sample_folder() / "ref", map_path, BuildOptions(model=a.model)))
        files = list_images(a.frames)
        heads = ("threads", "decode", "feature", "encode", "match", "total")
        variants = {"off": [False], "on": [True], "both": [False, True]}[a.standardise]
        for n, threads in enumerate(int(t) for t in a.threads.split(",")):
            locs = [Localizer(map_path, model=a.model, mode=a.matcher,
                              threads=threads if a.blas == "held" else None, standardise=v) for v in variants]
            if n == 0:
                print(f"{len(files)} frames from {a.frames}; map {len(locs[0].names)} refs x "
                      f"{locs[0].map.stored.shape[1]} dims; front end {locs[0].front_description}")
                print(f"BLAS pool: {a.blas}; standardise: {a.standardise}")
                print(" ".join(f"{h:>7s}" for h in heads) + "  ms/frame" + ("  variant" if len(locs) > 1 else ""))
            stages = timed_passes(locs, files, a.repeat)
            for v, st in zip(variants, stages):
                ms = 1e3 * st.mean(axis=0)
                print(f"{threads:7d} " + " ".join(f"{x:7.2f}" for x in ms) + f" {ms.sum():7.2f}"
                      + (f"  {'standardised' if v else 'plain'}" if len(locs) > 1 else ""))
            if len(locs) > 1:
                plain, std = (1e3 * st.sum(axis=1) for st in stages)   # ms a frame, each timed frame
                peaks = match_peaks(locs, files)
                print(f"{threads:7d} standardised / plain: frame mean {std.mean() / plain.mean():.3f}, "
                      f"median {np.median(std) / np.median(plain):.3f}; match stage mean "
                      f"{stages[1][:, 3].mean() / stages[0][:, 3].mean():.3f}; match peak allocated "
                      f"{peaks[0] / 1e3:.1f} / {peaks[1] / 1e3:.1f} kB (plain / standardised); process peak RSS "
                      f"{peak_rss_mb():.0f} MB (both)")
    return 0


def timed_passes(locs: list[Localizer], files: list[Path], repeat: int) -> list[np.ndarray]:
    """``repeat`` passes over ``files`` through each of ``locs`` (the stream started again each pass), the
    order of ``locs`` turned each pass so that each runs first as often; the first pass is warm-up. Returns
    each Localizer's seconds per stage of the timed passes ((repeat - 1) * F, 4), or the first pass's with
    ``repeat`` 1."""
    timed: list[list[np.ndarray]] = [[] for _ in locs]
    for r in range(max(repeat, 1)):
        for k in (range(len(locs)) if r % 2 == 0 else reversed(range(len(locs)))):
            locs[k].reset()
            stages, _ = time_stages(locs[k], files, load_image, len(files), 0)
            if r > 0 or repeat <= 1:
                timed[k].append(stages)
    return [np.concatenate(t) for t in timed]


def match_peaks(locs: list[Localizer], files: list[Path]) -> list[int]:
    """Each Localizer's peak bytes allocated (tracemalloc) while matching a pass of ``files`` (``push_encoding``
    on encodings made before; the stream started again), untimed."""
    encodings = [locs[0].encode([load_image(f)])[0] for f in files]
    peaks = []
    for loc in locs:
        loc.reset()
        tracemalloc.start()
        for e in encodings:
            loc.push_encoding(e)
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
    return peaks
