#!/usr/bin/env python3
"""Per-frame latency of the on-vehicle path, stage by stage, on real frames (batch size 1).

    python tools/bench_frame.py [--map MAP] [--frames DIR] [--threads 1,2] [--blas held|default]

Stages: decode (JPEG -> RGB), preprocess (resize, normalise), inference (ONNX tap), encode (IFV),
match (similarity row + matcher update). Without --map, one is built from the bundled sample's
references first (not timed). --blas held (default) limits NumPy's BLAS pool to the same thread count as
onnxruntime (what --threads does in the CLI); --blas default leaves BLAS at its own default (one thread per
core), for comparison; run the two in separate processes, since the limit is process-wide.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np


from vpr_edge.features.cnn import FeatureExtractor, default_model_path
from vpr_edge.images import list_images, load_image
from vpr_edge.map import build_map, load_map, map_front_end
from vpr_edge.map.front import map_model_path
from vpr_edge.matchers import get_matcher
from vpr_edge.resources import sample_folder
from vpr_edge.threads import use_threads


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--map", type=Path, default=None)
    p.add_argument("--model", type=Path, default=None)
    p.add_argument("--frames", type=Path, default=sample_folder() / "query")
    p.add_argument("--threads", default="1,2", help="onnxruntime thread counts to try")
    p.add_argument("--matcher", default="stream", help="registered online matcher")
    p.add_argument("--repeat", type=int, default=2, help="passes over the frames (the first is warm-up)")
    p.add_argument("--blas", choices=("held", "default"), default="held")
    a = p.parse_args()
    place_map = (load_map(a.map) if a.map else
                 build_map(list_images(sample_folder() / "ref"),
                           FeatureExtractor(a.model or default_model_path())))
    model = map_model_path(place_map, a.model)     # a given --model, else the map's own (as localize chooses)
    files = list_images(a.frames)
    print(f"{len(files)} frames from {a.frames}; map {len(place_map.names)} refs x {place_map.stored.shape[1]} "
          f"dims; model {model.name}")
    print(f"BLAS pool: {a.blas}")
    heads = ("threads", "decode", "prep", "infer", "encode", "match", "total")
    print(" ".join(f"{h:>7s}" for h in heads) + "  ms/frame")
    for threads in (int(t) for t in a.threads.split(",")):
        ex = map_front_end(place_map, a.map or "built map", model, use_threads(threads) if a.blas == "held" else threads)
        times = np.zeros(5)
        for rep in range(a.repeat):
            dtw = get_matcher(a.matcher).stream(len(place_map.names))
            times[:] = 0
            for f in files:
                t0 = time.perf_counter()
                rgb = load_image(f)
                t1 = time.perf_counter()
                x = ex.preprocess(rgb)[None]
                t2 = time.perf_counter()
                local = ex.local_features(x)
                t3 = time.perf_counter()
                enc = place_map.encode(local)[0]
                t4 = time.perf_counter()
                dtw.update(place_map.similarity(enc)[0])
                t5 = time.perf_counter()
                times += np.diff([t0, t1, t2, t3, t4, t5])
        ms = 1e3 * times / len(files)
        print(f"{threads:7d} " + " ".join(f"{v:7.2f}" for v in ms) + f" {ms.sum():7.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
