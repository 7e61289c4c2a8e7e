"""Per-frame latency of the on-vehicle path, stage by stage, on real frames (batch size 1).

    python -m vpr_edge_bench bench-frame [--map MAP] [--frames DIR] [--threads 1,2] [--blas held|default]

The chain timed is ``Localizer``'s own (``push`` = ``encode`` + ``push_encoding``), split into its stages:
decode (image file -> RGB), features (the front end: resize, normalise, ONNX tap), encode (the map's
encoder, IFV by default), match (``push_encoding``: the motion cue, the similarities the matcher asks for,
its update and the output line). Without --map, one is built from the bundled sample's references with
build-map's defaults (``write_map``; not timed). --blas held (default) limits NumPy's BLAS pool to the same
thread count as onnxruntime (what --threads does in the CLI); --blas default leaves BLAS at its own default
(one thread per core), for comparison; run the two in separate processes, since the limit is process-wide.
"""
from __future__ import annotations

import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vpr_edge import Localizer
from vpr_edge.frames.images import list_images, load_image
from vpr_edge.map.make import BuildOptions, plan_map, write_map
from vpr_edge.profiling.stages import time_stages
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
    a = p.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="vpr-edge-bench-") as tmp:
        map_path = a.map
        if map_path is None:   # the bundled sample's map, as build-map makes it
            map_path = Path(tmp) / "sample.map.npz"
            write_map(plan_map(sample_folder() / "ref", map_path, BuildOptions(model=a.model)))
        files = list_images(a.frames)
        heads = ("threads", "decode", "feature", "encode", "match", "total")
        for n, threads in enumerate(int(t) for t in a.threads.split(",")):
            loc = Localizer(map_path, model=a.model, mode=a.matcher,
                            threads=threads if a.blas == "held" else None)
            if n == 0:
                print(f"{len(files)} frames from {a.frames}; map {len(loc.names)} refs x "
                      f"{loc.map.stored.shape[1]} dims; front end {loc.front_description}")
                print(f"BLAS pool: {a.blas}")
                print(" ".join(f"{h:>7s}" for h in heads) + "  ms/frame")
            # passes over the frames, the stream started again for each: all but the last are warm-up
            stages, _ = time_stages(loc, files, load_image, len(files), len(files) * (a.repeat - 1))
            ms = 1e3 * stages.mean(axis=0)
            print(f"{threads:7d} " + " ".join(f"{v:7.2f}" for v in ms) + f" {ms.sum():7.2f}")
    return 0

