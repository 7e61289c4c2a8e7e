"""Where a map shows one view: the runs of references its drive saw alike, checked against the images.

    python -m vpr_edge_bench one-view-check --streams out/nordland-dev out/corridor [--tolerance 2]

For each folder (``derive-streams`` output: map.npz and the reference images it was built from, ref/), the
references the map's own motion cue reads as the view of the one before
(``evaluation.run.map_same_view``, what ``evaluate`` reads for its "other frames" shares) are grouped into runs
(each with the reference it repeats) and checked on the images themselves, independently of the front end:
per run its length, the images' mean brightness (0-255 grey; a dark run is a tunnel or a covered lens, not a
stop) and their mean absolute difference from the run's first image, against the route's median difference
between consecutive images; and how often a pixel rule (consecutive images differing by less than a quarter
of that median) flags the same references. Then per derived stream, the ``stream`` matcher's answers at
``--tolerance`` (``evaluate``): the wrong answers given and how many of them have their truth in a run.
Bad input is one line on stderr and exit code 2, before any work.
"""
from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from vpr_edge.evaluation.metrics import runs
from vpr_edge.evaluation.run import map_same_view
from vpr_edge.evaluation.truth import one_view
from vpr_edge.frames.images import load_image
from vpr_edge.map import load_map
from vpr_edge.matchers import get_matcher
from vpr_edge_bench.folder import streams_folders
from vpr_edge_bench.runner import parser, run_checked


def runs_of(same: np.ndarray) -> list[tuple[int, int]]:
    """(R,) bool, True where a reference shows the one before's view -> [first, last] of each run, the
    reference it repeats included."""
    return [(max(lo - 1, 0), hi - 1) for lo, hi in runs(same)]


def grey(path: Path) -> np.ndarray:
    """An image file -> its grey levels (H, W) float32, 0-255."""
    return cv2.cvtColor(load_image(path), cv2.COLOR_BGR2GRAY).astype(np.float32)


def main(argv: Sequence[str] | None = None) -> int:
    p = parser(__name__, __doc__)
    p.add_argument("--streams", type=Path, nargs="+", required=True, help="derived-streams folders with map.npz")
    p.add_argument("--tolerance", type=int, default=2)
    a = p.parse_args(argv)
    return run_checked(__name__, lambda: _run(a))


def _run(a: argparse.Namespace) -> int:
    for folder in streams_folders(a.streams, ref=True):
        pm = load_map(folder.map)
        same = map_same_view(pm.stored.in_order())
        images = np.stack([grey(folder.ref / name) for name in pm.names])
        step = np.abs(images[1:] - images[:-1]).mean(axis=(1, 2))
        typical = float(np.median(step))
        print(f"**{folder.name}**: {len(pm.names)} references, {int(same.sum())} show the view of the one before "
              f"(the route's median difference between consecutive images: {typical:.1f} grey levels)\n")
        pixel = np.r_[False, step < typical / 4]
        print(f"A pixel rule (consecutive images differ by less than {typical / 4:.1f}) flags {int(pixel.sum())} "
              f"references; it agrees with the map's motion cue on {np.mean(pixel == same):.1%} of them.\n")
        spans = runs_of(same)
        if spans:
            print("| run (references) | length | mean brightness | mean difference from its first image |")
            print("|---|---|---|---|")
            for lo, hi in spans:
                run = images[lo:hi + 1]
                print(f"| {lo}-{hi} | {hi - lo + 1} | {run.mean():.1f} | {np.abs(run - run[0]).mean():.2f} |")
            print()
        print(f"`stream` at ±{a.tolerance}: wrong answers given, and those whose truth lies in a run:\n")
        print("| stream | answers given | wrong | wrong, truth in a run |")
        print("|---|---|---|---|")
        for kind, ev in folder.evaluate({"stream": get_matcher("stream")}, a.tolerance):
            r = ev.reports["stream"]
            wrong = ~r.lost & ~r.correct
            at = one_view(ev.truth, same)
            print(f"| {kind} | {int((~r.lost).sum())} | {int(wrong.sum())} | {int((wrong & at).sum())} |")
        print()
    return 0

