"""Why the default matcher's lost frames are lost, on every derived stream of each dataset.

    python -m vpr_edge_bench lost-reasons --streams out/nordland-dev out/corridor [--tolerance 2]

For each folder (``derive-streams`` output with its map.npz) every stream is evaluated
(``evaluate``, the function behind ``vpr-edge evaluate``: the map's front end, the motion cue) with the
default ``stream`` matcher, and its lost frames are counted by the reason the matcher gives
(``matchers.LOST_WHY``: weak-view, no-trajectory, ambiguous), for frames of unmapped places and of mapped ones:
the counts ``vpr-edge evaluate`` prints per stream (``lost_why``), side by side for every stream, with one
figure of its own: of the mapped frames, those whose truth lies where the map shows one view
(``truth.one_view``). Bad input is
one line on stderr and exit code 2, before any work.
"""
from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vpr_edge.matchers import LOST_WHY, get_matcher
from vpr_edge_bench.folder import streams_folders
from vpr_edge_bench.runner import check_tolerance, parser, run_checked


def main(argv: Sequence[str] | None = None) -> int:
    p = parser(__name__, __doc__)
    p.add_argument("--streams", type=Path, nargs="+", required=True, help="derived-streams folders with map.npz")
    p.add_argument("--tolerance", type=int, default=2)
    a = p.parse_args(argv)
    return run_checked(__name__, lambda: _run(a))


def _run(a: argparse.Namespace) -> int:
    """The work of ``main``, inputs checked first."""
    check_tolerance(a.tolerance)
    folders = streams_folders(a.streams)
    print(f"default stream matcher, tolerance {a.tolerance}; lost frames by why: unmapped / mapped places "
          "(mapped frames whose truth lies at one view in brackets)\n")
    print("| dataset | stream | frames | unmapped | mapped | " + " | ".join(f"`{w}`" for w in LOST_WHY) + " |")
    print("|---|---|---|---|---|" + "---|" * len(LOST_WHY))
    for folder in folders:
        for kind, ev in folder.evaluate({"stream": get_matcher("stream")}, a.tolerance):
            r = ev.reports["stream"]
            mapped = (ev.truth >= 0).any(axis=1)
            at_view = mapped & (np.zeros(len(mapped), bool) if r.one_view is None else r.one_view)
            why = r.why if r.why is not None else np.full(len(mapped), None, object)
            cells = [f"{r.lost_why.get(w, {}).get('unmapped', 0)} / {r.lost_why.get(w, {}).get('mapped', 0)} "
                     f"({int(((why == w) & at_view).sum())})" for w in LOST_WHY]
            print(f"| {folder.name} | {kind} | {len(mapped)} | {int((~mapped).sum())} | {int(mapped.sum())} | "
                  + " | ".join(cells) + " |", flush=True)
    return 0
