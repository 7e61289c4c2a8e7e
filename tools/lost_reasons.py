#!/usr/bin/env python3
"""Why the default matcher's lost frames are lost, on every derived stream of each dataset.

    python tools/lost_reasons.py --streams out/nordland-dev out/corridor [--tolerance 2]

For each folder (``tools/derive_streams.py`` output with its map.npz) every stream is evaluated
(``evaluate``, the function behind ``vpr-edge evaluate``: the map's front end, the motion cue) with the
default ``stream`` matcher, and its lost frames are counted by the reason the matcher gives
(``matchers.LOST_WHY``: weak-view, no-trajectory, ambiguous), for frames of unmapped places and of mapped ones
(and, of the latter, those whose truth lies where the map shows one view, ``truth.one_view``). Bad input is
one line on stderr and exit code 2, before any work.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from vpr_edge.errors import VprError, one_line_errors
from vpr_edge.evaluation import Source, Truth, evaluate
from vpr_edge.evaluation.streams import KINDS, check_streams_folder
from vpr_edge.matchers import LOST_WHY, get_matcher


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--streams", type=Path, nargs="+", required=True, help="derive_streams folders with map.npz")
    p.add_argument("--tolerance", type=int, default=2)
    a = p.parse_args()
    return one_line_errors("lost_reasons", lambda: _run(a))


def _run(a: argparse.Namespace) -> int:
    """The work of ``main``, inputs checked first."""
    if a.tolerance < 0:
        raise VprError(f"--tolerance must be >= 0, got {a.tolerance}")
    for folder in a.streams:
        check_streams_folder(folder)
    mode = {"stream": get_matcher("stream")}
    print(f"default stream matcher, tolerance {a.tolerance}; lost frames by why: unmapped / mapped places "
          "(mapped frames whose truth lies at one view in brackets)\n")
    print("| dataset | stream | frames | unmapped | mapped | " + " | ".join(f"`{w}`" for w in LOST_WHY) + " |")
    print("|---|---|---|---|---|" + "---|" * len(LOST_WHY))
    for folder in a.streams:
        for kind in KINDS:
            ev = evaluate(Source(map=folder / "map.npz", queries=folder / kind), Truth(gt=folder / f"{kind}.csv"),
                          mode, a.tolerance)
            r = ev.reports["stream"]
            mapped = (ev.truth >= 0).any(axis=1)
            view = np.zeros(len(mapped), bool) if r.one_view is None else r.one_view
            why = r.why if r.why is not None else np.full(len(mapped), None, object)
            cells = []
            for w in LOST_WHY:
                is_w = why == w
                cells.append(f"{int((is_w & ~mapped).sum())} / {int((is_w & mapped).sum())} "
                             f"({int((is_w & mapped & view).sum())})")
            print(f"| {folder.name} | {kind} | {len(mapped)} | {int((~mapped).sum())} | {int(mapped.sum())} | "
                  + " | ".join(cells) + " |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
