"""Does the coarse whole-route search change what the stream matcher answers? Exact against coarse on real maps.

    python -m vpr_edge_bench coarse-check --map out/nordland-dev/map.npz --streams out/nordland-dev --keep 16 --calib 64

Each derived stream (STREAMS/KIND with STREAMS/KIND.csv) is encoded once through the map's front end
(``map.MapQuery``, the chain ``Localizer`` runs) and matched by the ``stream`` matcher twice (with each frame's
motion cue and the map's stops), frame by frame through ``matchers.step``:
every similarity exact (what ``evaluate`` measures), and with the frames that search the whole route served by
``coarse.CoarseSearch`` (signs, then exact values for the ``--keep`` best candidates and ``--calib`` random
references), as ``Localizer`` does on maps of 20,000+ references. The local-search frames are exact in both.
Prints R@1 / AUC and the lost shares of unmapped / mapped frames (``evaluation.scoring.score_result``, the figures of
``vpr-edge evaluate``; nan where a stream has no unmapped frames), the share of frames whose answers agree and
the share of whole-route frames, per stream.
"""
from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vpr_edge.evaluation import truth as groundtruth
from vpr_edge.evaluation.scoring import score_result
from vpr_edge.frames.images import list_images, load_image
from vpr_edge.index.coarse import CoarseSearch
from vpr_edge.map import MapQuery
from vpr_edge.matchers import get_matcher, run_online, run_rows
from vpr_edge.matchers.route import RouteGraph
from vpr_edge.threads import use_threads
from vpr_edge_bench.folder import StreamsFolder
from vpr_edge_bench.runner import parser, run_checked
from vpr_edge_bench.streams import KINDS


def main(argv: Sequence[str] | None = None) -> int:
    p = parser(__name__, __doc__)
    p.add_argument("--map", type=Path, required=True)
    p.add_argument("--streams", type=Path, required=True, help="a derived-streams folder: KIND/ and KIND.csv")
    p.add_argument("--kinds", default=",".join(KINDS))
    p.add_argument("--keep", type=int, default=1024, help="exact values for the best KEEP by sign agreement")
    p.add_argument("--calib", type=int, default=512, help="exact values of CALIB fixed random references")
    p.add_argument("--tolerance", type=int, default=1)
    p.add_argument("--threads", type=int, default=0)
    a = p.parse_args(argv)
    return run_checked(__name__, lambda: _run(a))


def _run(a: argparse.Namespace) -> int:
    """The work of ``main``, the streams checked first."""
    folder = StreamsFolder(a.streams, [k for k in a.kinds.split(",") if k]).check(map=False)
    query = MapQuery(a.map, ort_threads=use_threads(a.threads))   # the map and its front end, as localize opens them
    place_map = query.map
    matcher = get_matcher("stream").on_route(query.references(), RouteGraph(*query.joins()))
    r = len(place_map.names)
    print(f"map {a.map}: {r} references x {place_map.stored.shape[1]} dims {place_map.stored.storage}; "
          f"keep {a.keep}, calib {a.calib}, tolerance {a.tolerance}")
    print("| stream | exact R@1 / AUC | coarse R@1 / AUC | exact lost unmapped / mapped | coarse lost unmapped / "
          "mapped | same answer | whole-route frames |")
    print("|---|---|---|---|---|---|---|")
    for kind in folder.kinds:
        files = list_images(folder.frames(kind))
        truth = groundtruth.load_csv(folder.truth(kind))
        enc = np.concatenate([query.encode([load_image(f) for f in files[i:i + 16]]) for i in range(0, len(files), 16)])
        cue = matcher.cue(enc)   # each frame's motion cue, as localize computes it
        exact = place_map.similarity(enc)
        coarse = CoarseSearch(place_map.stored, keep=a.keep, calib=a.calib)
        whole = [0]

        def rows(i: int, idx: np.ndarray | None) -> np.ndarray:
            if idx is not None:
                return exact[i, idx]
            whole[0] += 1
            return coarse.similarity(enc[i])

        base = run_online(matcher.stream(r), exact, still=cue)
        approx = run_rows(matcher.stream(r), rows, len(enc), r, still=cue)
        s0 = score_result(base, truth, a.tolerance, matcher.min_confidence)
        s1 = score_result(approx, truth, a.tolerance, matcher.min_confidence)
        print(f"| {kind} | {s0.recall[1]:.3f} / {s0.auc:.3f} | {s1.recall[1]:.3f} / {s1.auc:.3f} | "
              f"{s0.lost_unmapped:.3f} / {s0.lost_mapped:.3f} | {s1.lost_unmapped:.3f} / {s1.lost_mapped:.3f} | "
              f"{float(np.mean(base.refs == approx.refs)):.3f} | {whole[0] / len(enc):.2f} |", flush=True)
    return 0

