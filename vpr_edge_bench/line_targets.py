"""The targets of the lost line, counted over streams: pure functions over each stream's figures or answers.

``front-end-lines`` (``experiments.front_end_lines``) runs every mode on every cached front end and stream and
prints these: which streams meet each target of the line (``targets``), the line that would meet the most of
them for one front end, chosen with the truth (``best_line``: what the mode's ranking allows), the
reliability of a probability (``reliability``) and how far ahead of the truth a front end sees (``lead``).
"""
from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from vpr_edge.evaluation import metrics

GAP = 0.05              # the largest line gap a stream meets the target with
FOLLOWED = 0.5          # the best answers' R@1 of a stream the matcher follows (right for most of its frames)
UNMAPPED_LOST = 0.95    # the detour's unmapped frames lost
FOREIGN_LOST = 0.99     # foreign imagery lost
EDGES = (0.5, 0.8, 0.9, 0.95, 0.98, 1.0)   # the reliability table's bins of the probability (the last closed)
LEAD_REACH = 8          # references either side of the truth where a frame's best match gives the lead


@dataclasses.dataclass(frozen=True)
class StreamFigures:
    """One mode's figures on one stream (``ModeReport``'s, NaN where they do not apply: foreign imagery has
    only ``unmapped_lost``, and only the detour and foreign imagery have that); ``single``: the front end
    alone's R@1, ``first_exit``: frames until the first lost one after leaving the map (NaN: none lost there;
    None: the mode has no lost state or the stream no unmapped run); ``exact``: mapped frames answered at the
    truth's place itself, ``lead``: the mean signed error of the right answers, in places (+: ahead)."""

    best_r1: float
    answered_right: float
    distinct_answered_right: float
    mapped_right: float
    best_line: float
    line_gap: float
    unmapped_lost: float
    stream: str = ""
    single: float = float("nan")
    first_exit: float | None = None
    exact: float = float("nan")
    lead: float = float("nan")


def targets(streams: Sequence[StreamFigures], foreign: Sequence[float] | None,
            target: float) -> dict[str, tuple[int, int]]:
    """Per target of the line, how many of one dataset's ``streams`` (one mode, every front end) meet it, as
    (met, of) (``count_text`` writes it): line gap (of the streams where it is defined), target precision where
    eligible (over every frame; over the distinct frames, where a stream has one-view frames; a stream with no
    answer does not meet it, and the eligible streams with none are counted apart), not silent where eligible
    and where followed (best R@1 >= ``FOLLOWED``) but not eligible, the detour's unmapped frames lost, and with
    ``foreign`` (each front end's share of foreign imagery lost; None: not measured) foreign imagery."""
    def count(met: Sequence[bool]) -> tuple[int, int]:
        return int(sum(met)), len(met)

    def allows(f: StreamFigures) -> bool:
        return f.best_line > 0 and f.best_line >= 0.5 * f.best_r1

    gaps = [f.line_gap for f in streams if not np.isnan(f.line_gap)]
    eligible = [f for f in streams if allows(f)]
    beyond = [f for f in streams if not allows(f) and f.best_r1 >= FOLLOWED]
    distinct = [f.answered_right if np.isnan(f.distinct_answered_right) else f.distinct_answered_right
                for f in eligible]
    detours = [f.unmapped_lost for f in streams if not np.isnan(f.unmapped_lost)]
    out = {"line gap <= %.2f" % GAP: count([g <= GAP for g in gaps]),
           "precision >= target where eligible": count([f.answered_right >= target for f in eligible]),
           "... over distinct frames": count([d >= target for d in distinct]),
           "... none answered": count([bool(np.isnan(f.answered_right)) for f in eligible]),
           "not silent where eligible": count([f.mapped_right >= 0.5 * f.best_r1 for f in eligible]),
           "... followed, not eligible": count([f.mapped_right >= 0.5 * f.best_r1 for f in beyond]),
           "detour unmapped lost >= %.2f" % UNMAPPED_LOST: count([d >= UNMAPPED_LOST for d in detours])}
    if foreign is not None:
        out["foreign lost >= %.2f" % FOREIGN_LOST] = count([x >= FOREIGN_LOST for x in foreign])
    return out


@dataclasses.dataclass(frozen=True)
class StreamAnswers:
    """One mode's answers on one stream, for lines drawn afresh (``line_figures``): each frame's ``scores``,
    whether it was ``right`` and ``mapped``, whether its truth lies where the map shows one view, the best
    answers' R@1 and the best line's recall at the target (the mode's ranking; NaN on foreign imagery)."""

    stream: str
    scores: np.ndarray
    right: np.ndarray
    mapped: np.ndarray
    one_view: np.ndarray
    best_r1: float = float("nan")
    best_line: float = float("nan")


def line_figures(answers: StreamAnswers, line: float) -> StreamFigures:
    """The figures of ``answers`` lost below the score ``line``, the line gap as ``evaluate`` counts it (the
    best line on the scores at the precision delivered, minus the recall delivered)."""
    given = answers.scores >= line
    nan = float("nan")
    if answers.stream == "foreign":
        return StreamFigures(nan, nan, nan, nan, nan, nan, float((~given).mean()), answers.stream)
    answered_right, mapped_right = metrics.answered_shares(answers.right, ~given, answers.mapped)
    keep = ~answers.one_view
    distinct = metrics.answered_shares(answers.right[keep], ~given[keep], answers.mapped[keep])[0] \
        if answers.one_view.any() else nan
    unmapped = float((~given[~answers.mapped]).mean()) if answers.stream == "detour" and (~answers.mapped).any() \
        else nan
    curve = metrics.pr_curve(answers.scores, answers.right, int(answers.mapped.sum()))
    gap = metrics.line_gap(curve, answered_right, mapped_right)
    return StreamFigures(answers.best_r1, answered_right, distinct, mapped_right, answers.best_line, gap, unmapped,
                         answers.stream)


def count_text(counts: dict[str, tuple[int, int]]) -> dict[str, str]:
    """``targets``' counts as "met/of"."""
    return {k: f"{met}/{of}" for k, (met, of) in counts.items()}


def best_line(streams: Sequence[StreamAnswers], target: float,
              candidates: int = 200) -> tuple[float, dict[str, tuple[int, int]]]:
    """The one line on the score that meets the most targets of ``streams`` (one front end's, foreign imagery
    among them), chosen with their truth (what the mode's ranking allows; ``targets``): among ``candidates``
    quantiles of the scores (and no answer at all), those meeting the most of the targets a vehicle acts on
    (precision where eligible, over the distinct frames where a stream has one-view frames, the detour and
    foreign imagery lost), of those the ones not silent on the most streams, of those the lowest.
    -> (the line, its ``targets`` counts)."""
    every = np.concatenate([a.scores for a in streams])
    lines = np.unique(np.r_[np.quantile(every, np.linspace(0, 1, candidates)), np.inf])
    safe = ("... over distinct frames", "detour unmapped lost", "foreign lost")
    best: tuple[tuple[int, int], float, dict[str, tuple[int, int]]] | None = None
    for line in lines:
        figs = [line_figures(a, line) for a in streams]
        foreign = [f.unmapped_lost for f in figs if f.stream == "foreign"]
        counts = targets([f for f in figs if f.stream != "foreign"], foreign or None, target)
        met = {k: v[0] for k, v in counts.items()}
        rank = (sum(v for k, v in met.items() if k.startswith(safe)),
                sum(v for k, v in met.items() if "silent" in k or k.startswith("... followed")))
        if best is None or rank > best[0]:
            best = (rank, float(line), counts)
    assert best is not None
    return best[1], best[2]


def reliability(probability: np.ndarray, right: np.ndarray, edges: Sequence[float] = EDGES) -> list[tuple[float, int]]:
    """Per bin [edges[i], edges[i+1]) of ``probability`` (Q,) (the last bin closed): (the share of ``right``
    (Q,) bool among the answers in it, NaN where none; how many)."""
    p, ok = np.asarray(probability, np.float64), np.asarray(right, bool)
    out = []
    for i, (lo, hi) in enumerate(zip(edges[:-1], edges[1:])):
        inside = (p >= lo) & ((p <= hi) if i == len(edges) - 2 else (p < hi))
        out.append((float(ok[inside].mean()) if inside.any() else float("nan"), int(inside.sum())))
    return out


def lead(sim: np.ndarray, truth: np.ndarray, reach: int = LEAD_REACH) -> np.ndarray:
    """How far ahead of the truth each mapped frame's best match lies, among the references within ``reach``
    of it: ``sim`` (Q, R), ``truth`` (Q, T) padded with -1 (its first column the truth) -> (M,) int, one per
    mapped frame (negative: behind)."""
    t = np.asarray(truth)[:, 0]
    rows = np.flatnonzero(t >= 0)
    cols = t[rows, None] + np.arange(-reach, reach + 1)
    valid = (cols >= 0) & (cols < sim.shape[1])
    near = np.where(valid, np.asarray(sim)[rows[:, None], np.clip(cols, 0, sim.shape[1] - 1)], -np.inf)
    return np.argmax(near, axis=1) - reach
