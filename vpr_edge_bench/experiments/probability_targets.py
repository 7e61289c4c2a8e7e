"""Does a mode's probability keep its word on every front end? Its targets, per dataset and front end.

    python -m vpr_edge_bench probability-targets --cache out/fronts --modes stream

From the similarity matrices ``front-end-cache`` wrote, each mode (a registered matcher whose score is a
probability, or ``NAME:KEY=VALUE[;KEY=VALUE]``) runs on every derived stream; tolerance 2 (the derived
streams' truth names one place). One row per dataset and front end:

- ``p>=0.90`` .. ``p>=0.98``: the share right of the answers whose probability reaches the line, pooled over
  the streams (their count in brackets; ``-`` below 50 answers), the frames whose truth lies where the map
  shows one view left out; a calibrated probability keeps each at least the line less 0.02;
- ``ECE``: the expected calibration error over the same answers, every probability (10 bins);
- ``subtracts``: the streams whose best answers' R@1 is below the better of one frame alone (``single``) and
  online SeqSLAM less 0.01 (the sequence takes away);
- ``right@P / line``: mapped frames answered right at the line ``--target-precision`` against the best line's
  recall at the same precision on the same probabilities (not silent: at least 0.7 of it);
- ``lost off``: the detour's unmapped frames lost, and foreign imagery (the other dataset's frames) lost.
"""
from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vpr_edge.matchers.constants import TARGET_PRECISION
from vpr_edge.errors import VprError
from vpr_edge_bench.experiments.front_end_lines import check_cache, load, matcher_of
from vpr_edge_bench.runner import parser, run_checked

LINES = (0.90, 0.95, 0.98)   # the probability lines whose precision is read
MIN_ANSWERS = 50             # fewer answers at a line: its precision is not read
TOLERANCE = 2
PEERS = ("single", "seqslam-online")   # what the sequence must not fall below


def run_mode(mode: str, case: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """``mode`` on a cached stream -> (answers (Q,) int, probability (Q,); the score if it has none)."""
    m = matcher_of(mode)
    if m.reads_route and "route" in case:
        m = dataclasses.replace(m, route=case["route"].astype(bool), reach=int(case["reach"]))
    r = m.run(case["sim"], k=1, still=case.get("cue"))
    return np.asarray(r.refs), np.asarray(r.scores if r.probability is None else r.probability, np.float64)


def is_right(answers: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(Q,) answers, (Q,) true place (-1: unmapped) -> (Q,) bool, within ``TOLERANCE``."""
    return (truth >= 0) & (np.abs(answers - truth) <= TOLERANCE)


def best_line_recall(p: np.ndarray, right: np.ndarray, precision: float) -> float:
    """The highest share of all (Q,) frames answered right by any line on ``p`` whose answers are right for at
    least ``precision`` (0 if none)."""
    order = np.argsort(-p, kind="stable")
    hits = np.cumsum(right[order])
    ok = hits / np.arange(1, len(p) + 1) >= precision
    return float(hits[ok].max()) / len(p) if ok.any() else 0.0


def ece(p: np.ndarray, right: np.ndarray, bins: int = 10) -> float:
    """Expected calibration error of probabilities (N,) against outcomes (N,) bool, ``bins`` equal bins."""
    k = np.clip((p * bins).astype(int), 0, bins - 1)
    total = 0.0
    for b in np.unique(k):
        sel = k == b
        total += abs(float(right[sel].mean()) - float(p[sel].mean())) * int(sel.sum())
    return total / max(len(p), 1)


def front_row(mode: str, folder: Path, target: float) -> str:
    """One dataset's front end (a folder of cached streams) -> its row of the table."""
    pooled_p, pooled_ok, mapped_p, mapped_ok, subtracts = [], [], [], [], []
    detour = foreign = "-"
    for f in sorted(folder.glob("*.npz")):
        case = load(f)
        if "sim" not in case:
            continue
        answers, p = run_mode(mode, case)
        if f.stem == "foreign":
            foreign = f"{float((p < target).mean()):.3f}"
            continue
        truth = case["truth"][:, 0]
        mapped = truth >= 0
        ok = is_right(answers, truth)
        keep = mapped & ~case["one_view"].astype(bool) if "one_view" in case else mapped
        pooled_p.append(p[keep]); pooled_ok.append(ok[keep])
        mapped_p.append(p[mapped]); mapped_ok.append(ok[mapped])
        peer = max(float(is_right(run_mode(m, case)[0], truth)[mapped].mean()) for m in PEERS)
        if ok[mapped].mean() < peer - 0.01:
            subtracts.append(f.stem)
        if f.stem == "detour" and (~mapped).any():
            detour = f"{float((p[~mapped] < target).mean()):.3f}"
    p, ok = np.concatenate(pooled_p), np.concatenate(pooled_ok)
    cells = []
    for line in LINES:
        sel = p >= line
        cells.append(f"{ok[sel].mean():.3f} ({sel.sum()})" if sel.sum() >= MIN_ANSWERS else f"- ({sel.sum()})")
    mp, mok = np.concatenate(mapped_p), np.concatenate(mapped_ok)
    answered = mp >= target
    right_at = float((mok & answered).mean())
    precision = float(mok[answered].mean()) if answered.any() else target
    line = best_line_recall(mp, mok, min(precision, target))
    sub = ", ".join(subtracts) if subtracts else "none"
    return (f"| {folder.parent.name} | {folder.name} | {' | '.join(cells)} | {ece(p, ok):.3f} | {sub} | "
            f"{right_at:.2f} / {line:.2f} | {detour} / {foreign} |")


def main(argv: Sequence[str] | None = None) -> int:
    p = parser(__name__, __doc__)
    p.add_argument("--cache", type=Path, required=True)
    p.add_argument("--modes", default="stream", help="comma-separated modes (NAME or NAME:KEY=VALUE;...)")
    p.add_argument("--fronts", default=None, help="comma-separated front ends (default: every one cached)")
    p.add_argument("--target-precision", type=float, default=TARGET_PRECISION)
    a = p.parse_args(argv)
    return run_checked(__name__, lambda: _run(a))


def _run(a: argparse.Namespace) -> int:
    """The work of ``main``, the cache, the modes and the line checked first."""
    check_cache(a.cache, a.modes)
    if not 0.0 < a.target_precision < 1.0:
        raise VprError(f"--target-precision {a.target_precision}: must lie in (0, 1)")
    fronts = None if a.fronts is None else set(a.fronts.split(","))
    head = " | ".join(f"p>={line:.2f}" for line in LINES)
    for mode in a.modes.split(","):
        print(f"\n{mode}: tolerance {TOLERANCE}, line {a.target_precision}\n")
        print(f"| dataset | front end | {head} | ECE | subtracts | right@P / line | lost off (detour / foreign) |")
        print("|---" * (len(LINES) + 6) + "|")
        for ds in sorted(d for d in a.cache.iterdir() if d.is_dir() and d.name != "models"):
            for folder in sorted(d for d in ds.iterdir() if d.is_dir()):
                if fronts is None or folder.name in fronts:
                    print(front_row(mode, folder, a.target_precision), flush=True)
    return 0
