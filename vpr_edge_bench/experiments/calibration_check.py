"""Does a confidence calibrated on one dataset mean the same on another? Leave one dataset out, both ways.

    python -m vpr_edge_bench calibration-check --streams out/corridor out/nordland-dev [--modes stream-rules]

For each mode, the answers of every derived stream of one dataset (``evaluate``, the function behind
``vpr-edge evaluate``, on STREAMS/KIND with the map STREAMS/map.npz and ground truth STREAMS/KIND.csv, so the
stream mode gets its motion cue as ``localize`` does) are pooled and a calibration is fitted on their answers given (``vpr_edge.calibration.fit``, what ``evaluate
--save-calibration`` writes; each fit of ``--fits``); it is then scored on every stream of the other dataset
and of its own: the expected calibration error over the answers given (``metrics.reliability``, 10 bins;
a lost frame carries no confidence; also over the answers whose truth does not lie where the map shows one
view, ``truth.one_view``), the pooled Brier score (``metrics.brier``), and beside them the ECE and Brier
score of a constant confidence, the calibration dataset's share of answers right (what a confidence that tells
no answer from another scores), the share of answered frames right and of mapped frames answered right at the
mode's lost threshold. ``--write DIR`` keeps each fitted
calibration as DIR/DS.json (for ``localize --calibration`` / ``evaluate --calibration``).
"""
from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vpr_edge import calibration
from vpr_edge.errors import VprError
from vpr_edge.evaluation import metrics
from vpr_edge.matchers import get_matcher
from vpr_edge_bench.folder import streams_folders
from vpr_edge_bench.runner import parser, run_checked
from vpr_edge_bench.streams import KINDS


def main(argv: Sequence[str] | None = None) -> int:
    p = parser(__name__, __doc__)
    p.add_argument("--streams", type=Path, nargs=2, required=True,
                   help="two derived-streams folders (DS = name), each with its map.npz")
    p.add_argument("--modes", default="stream-rules,single")
    p.add_argument("--tolerance", type=int, default=2)
    p.add_argument("--fits", default=calibration.DEFAULT_METHOD,
                   help=f"calibration fits, comma-separated ({', '.join(calibration.METHODS)})")
    p.add_argument("--write", type=Path, default=None)
    a = p.parse_args(argv)
    return run_checked(__name__, lambda: _run(a))


def _run(a: argparse.Namespace) -> int:
    """The work of ``main``, inputs checked first: --fits, --modes, both folders."""
    fits = [f for f in a.fits.split(",") if f]
    if not fits or any(f not in calibration.METHODS for f in fits):
        raise VprError(f"--fits {a.fits!r}: choose from {', '.join(calibration.METHODS)}")
    try:
        modes = {m: get_matcher(m) for m in a.modes.split(",")}
    except ValueError as e:
        raise VprError(f"--modes: {e}") from None
    folders = streams_folders(a.streams)
    every = {(folder.name, kind): ev.reports for folder in folders
             for kind, ev in folder.evaluate(modes, a.tolerance)}
    for mode, fit in ((m, f) for m in modes for f in fits):
        reports = {key: r[mode] for key, r in every.items()}
        curves, base_rate = {}, {}
        for folder in folders:
            mine = [r for (ds, _), r in reports.items() if ds == folder.name]
            curves[folder.name] = calibration.fit(np.concatenate([r.scores for r in mine]),
                                                  np.concatenate([r.correct for r in mine]), a.tolerance,
                                                  np.concatenate([~r.lost for r in mine]), fit)
            base_rate[folder.name] = np.concatenate([r.correct[~r.lost] for r in mine]).mean()   # its share right
            if a.write:
                a.write.mkdir(parents=True, exist_ok=True)
                calibration.write(a.write / f"{folder.name}.json", {mode: curves[folder.name]},
                                  f"{folder.path} (all derived streams)", fit)
        print(f"\n{mode}, tolerance {a.tolerance}, {fit} fit: ECE of the confidence over the answers given per "
              f"stream, calibrated on each dataset\n")
        print("| scored on | calibrated on | " + " | ".join(KINDS) + " | all | all, other frames | all: Brier | "
              "a constant: ECE / Brier | answered right | mapped right |")
        print("|---|---|" + "---|" * (len(KINDS) + 6))
        for folder in folders:
            mine = [reports[folder.name, k] for k in KINDS]
            for fitted in folders:
                curve = curves[fitted.name]
                eces = [metrics.reliability(curve.of(r.scores[~r.lost]), r.correct[~r.lost])[0] for r in mine]
                given = np.concatenate([r.scores[~r.lost] for r in mine])
                right = np.concatenate([r.correct[~r.lost] for r in mine])
                pooled = metrics.reliability(curve.of(given), right)[0]
                flat = np.full(len(right), base_rate[fitted.name])   # no answer told from another
                constant = f"{metrics.reliability(flat, right)[0]:.3f} / {metrics.brier(flat, right):.3f}"
                other = [~r.lost & ~_at_one_view(r) for r in mine]
                apart = metrics.reliability(curve.of(np.concatenate([r.scores[o] for r, o in zip(mine, other)])),
                                            np.concatenate([r.correct[o] for r, o in zip(mine, other)]))[0]
                own = " (own)" if fitted.path == folder.path else ""
                print(f"| {folder.name} | {fitted.name}{own} | " + " | ".join(f"{e:.3f}" for e in eces)
                      + f" | {pooled:.3f} | {apart:.3f} | {metrics.brier(curve.of(given), right):.3f} | {constant} | "
                      + " / ".join(f"{r.answered_right:.3f}" for r in mine)
                      + " | " + " / ".join(f"{r.mapped_right:.3f}" for r in mine) + " |")
    return 0


def _at_one_view(report) -> np.ndarray:
    """(Q,) bool: the frames whose truth lies where the map shows one view (none where not known)."""
    return np.zeros(len(report.scores), bool) if report.one_view is None else report.one_view

