"""Evaluation of matchers on one similarity matrix against ground truth (pure arrays in, a report out)."""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from vpr_edge.calibration import Curve
from vpr_edge.matchers import Matcher, Result, is_lost, lost_why
from vpr_edge.matchers.base import reasons_of
from vpr_edge.matchers.base import StreamRows
from vpr_edge.matchers.constants import TARGET_PRECISION
from vpr_edge.evaluation import metrics
from vpr_edge.positions import Positions

RECALL_KS: tuple[int, ...] = (1, 5, 10)


@dataclass(frozen=True)
class ModeReport:
    """One matcher's figures. ``lost_unmapped``/``lost_mapped``: share of frames of unmapped / mapped places
    whose score is below the matcher's lost threshold (NaN where it has none or no such frames).
    ``settings``: the matcher's parameters and the lost threshold it was scored with. ``lock_frames``: per run
    of mapped frames (the stream's start, each re-entry), frames until the first confident correct answer;
    ``exit_frames``: per run of unmapped frames, frames until the first lost one (empty without a lost state);
    NaN where it did not happen within the run (``metrics.transition_delays``)."""

    recall: dict[int, float]
    auc: float
    ap: float
    precision_at_full_recall: float
    recall_at_full_precision: float
    median_error: float
    lost_unmapped: float
    lost_mapped: float
    match_ms: float
    curve: metrics.PRCurve
    settings: dict[str, Any] = field(default_factory=dict)
    lock_frames: tuple[float, ...] = ()
    exit_frames: tuple[float, ...] = ()
    metres: dict[str, float] | None = None    # with a map's positions: ``metrics.metre_summary``
    refs: np.ndarray | None = field(default=None, repr=False, compare=False)      # (Q,) each frame's answer
    lost: np.ndarray | None = field(default=None, repr=False, compare=False)      # (Q,) bool
    correct: np.ndarray | None = field(default=None, repr=False, compare=False)   # (Q,) bool, within tolerance
    scores: np.ndarray | None = field(default=None, repr=False, compare=False)    # (Q,) each answer's score
    one_view: np.ndarray | None = field(default=None, repr=False, compare=False)  # (Q,) bool: ``truth.one_view``
    answered_right: float = float("nan")   # share of answered (not lost) frames that are right
    mapped_right: float = float("nan")     # share of mapped frames answered right
    ece: float = float("nan")              # with a calibration: expected calibration error of the confidence
    reliability: tuple = ()                # ... and its reliability table (metrics.reliability)
    one_view_frames: int = -1              # mapped frames whose truth lies where the map shows one view
    distinct_answered_right: float = float("nan")   # answered_right and mapped_right over the other frames
    distinct_mapped_right: float = float("nan")     # (-1, NaN: the map's views not known; ``truth.one_view``)
    why: np.ndarray | None = field(default=None, repr=False, compare=False)       # (Q,) object: ``lost_why``
    lost_why: dict[str, dict[str, int]] = field(default_factory=dict)   # reason -> {"unmapped": n, "mapped": n}
    target_precision: float = TARGET_PRECISION   # the precision the best line is read at
    best_line_recall: float = float("nan")  # the best line's recall (mapped right) at the target precision
    line_gap: float = float("nan")          # the best line's recall at the delivered precision - mapped_right
    probability: bool = False               # the scores lie on the precision scale (a target precision line)
    exact: float = float("nan")            # share of mapped frames answered at the truth's middle place
    lead: float = float("nan")             # mean answer - truth's middle over the right answers, frames
    probabilities: np.ndarray | None = field(default=None, repr=False, compare=False)   # (Q,) each answer's
    # probability of being right, where the matcher models one

    def as_json(self) -> dict:
        """The keys of ``evaluate --json`` (NaN as null)."""
        def num(v: float) -> float | None:
            return None if np.isnan(v) else round(float(v), 6)
        return {f"recall_at_{k}": num(v) for k, v in self.recall.items()} | {
            "auc": num(self.auc), "ap": num(self.ap),
            "precision_at_full_recall": num(self.precision_at_full_recall),
            "recall_at_full_precision": num(self.recall_at_full_precision),
            "median_error": num(self.median_error), "lost_unmapped": num(self.lost_unmapped),
            "lost_mapped": num(self.lost_mapped), "ms_per_frame": num(self.match_ms),
            "lock_frames": [num(v) for v in self.lock_frames], "exit_frames": [num(v) for v in self.exit_frames],
            "answered_right": num(self.answered_right), "mapped_right": num(self.mapped_right),
            "ece": num(self.ece), "reliability": list(self.reliability),
            "one_view_frames": self.one_view_frames, "distinct_answered_right": num(self.distinct_answered_right),
            "distinct_mapped_right": num(self.distinct_mapped_right), "lost_why": self.lost_why,
            "target_precision": self.target_precision, "best_line_recall": num(self.best_line_recall),
            "line_gap": num(self.line_gap), "exact": num(self.exact), "lead": num(self.lead),
            "settings": self.settings} | ({"metres": {k: num(v) for k, v in self.metres.items()}}
                                          if self.metres is not None else {})


def evaluate_mode(matcher: Matcher, sim: np.ndarray, truth: np.ndarray, tolerance: int = 1,
                  min_confidence: float | None = None, positions: Positions | None = None,
                  calibration: Curve | None = None, still: np.ndarray | None = None,
                  drive: np.ndarray | None = None, one_view: np.ndarray | None = None,
                  target_precision: float | None = None, search: StreamRows | None = None) -> ModeReport:
    """Run ``matcher`` on ``sim`` (Q, R) and score it against ``truth`` (Q, T) padded (see metrics); with the
    references' ``positions``, the error in metres too; with a ``calibration`` (score -> probability right,
    ``vpr_edge.calibration.Curve``, fitted on other data), its expected calibration error over the answers
    given, and with a ``target_precision`` the lost line its drive's answers reached it at (``Curve.line``,
    as ``Localizer`` draws it); without one, for a matcher whose score is a probability
    (``Matcher.probability``), that probability's over every frame (it is the answer's, lost or not).
    ``still`` (Q,): each
    frame's motion cue (``Matcher.cue`` of the query encodings; None: a bare similarity matrix). ``drive`` (R,):
    each reference's drive in a map of several (answers within ``tolerance`` count only in the truth's drive).
    ``one_view`` (Q,) bool: the frames whose truth lies where the map shows one view (``truth.one_view``): the
    answered / mapped right shares are also given over the other frames. ``target_precision``: the line of a
    matcher whose score is a probability (``Matcher.lost_line``) and where the best line is read (default
    ``constants.TARGET_PRECISION``). ``search``: the rows an online matcher reads as ``Localizer`` reads them
    (``Matcher.run``; None: the rows of ``sim``)."""
    t0 = time.perf_counter()
    result = matcher.run(sim, k=max(RECALL_KS), still=still, search=search)
    ms = 1e3 * (time.perf_counter() - t0) / len(sim)
    line = None if calibration is None else calibration.target_line()
    threshold = matcher.lost_line(min_confidence, target_precision, line=line)
    target = TARGET_PRECISION if target_precision is None else target_precision
    report = replace(score_result(result, truth, tolerance, threshold, ms, positions, drive, one_view, target),
                     settings=matcher.params | {"min_confidence": threshold}, probability=matcher.probability)
    if calibration is not None:   # over the answers given: a lost frame carries no confidence
        given = ~report.lost
        ece, table = metrics.reliability(calibration.of(report.scores[given]), report.correct[given])
        report = replace(report, ece=ece, reliability=tuple(table))
    elif report.probabilities is not None:   # the probability that each frame's answer is right, lost or not
        ece, table = metrics.reliability(report.probabilities, report.correct)
        report = replace(report, ece=ece, reliability=tuple(table))
    return report


def score_result(result: Result, truth: np.ndarray, tolerance: int = 1, threshold: float | None = None,
                 match_ms: float = float("nan"), positions: Positions | None = None,
                 drive: np.ndarray | None = None, one_view: np.ndarray | None = None,
                 target_precision: float = TARGET_PRECISION) -> ModeReport:
    """A matcher's answers (``Result``, Q frames) against ``truth`` (Q, T); frames scoring below
    ``threshold`` count as lost (None: no lost state); ``drive``, ``one_view``: as ``evaluate_mode``'s; the
    best line (the answers ranked by score) read at ``target_precision`` and at the delivered precision."""
    mapped = (truth >= 0).any(axis=1)
    correct = metrics.correct_candidates(result.ranked, truth, tolerance, drive)
    curve = metrics.pr_curve(result.scores, correct[:, 0], int(mapped.sum()))
    err = metrics.localisation_error(result.refs, truth, drive)
    lost = is_lost(result.scores, threshold)

    def share(mask: np.ndarray) -> float:
        return float(lost[mask].mean()) if threshold is not None and mask.any() else float("nan")

    lock, exits = metrics.transition_delays(mapped, correct[:, 0] & ~lost, lost)
    answered_right, mapped_right = metrics.answered_shares(correct[:, 0], lost, mapped)
    exact, lead = metrics.exact_and_lead(result.refs, truth, correct[:, 0], lost)
    why = None if result.why is None else np.array([lost_why(w, bool(x)) for w, x in zip(result.why, lost)], object)
    reasons = {} if why is None else {r: {"unmapped": int(((why == r) & ~mapped).sum()),
                                          "mapped": int(((why == r) & mapped).sum())} for r in reasons_of(result.why)}
    view = None if one_view is None else np.asarray(one_view, bool)
    distinct = (-1, float("nan"), float("nan"))
    if view is not None:
        distinct = (int((mapped & view).sum()), *metrics.answered_shares(correct[~view, 0], lost[~view], mapped[~view]))
    return ModeReport({k: metrics.recall_at_k(correct, mapped, k) for k in RECALL_KS},
                      metrics.auc_trapezoid(curve), metrics.average_precision(curve),
                      metrics.precision_at_full_recall(curve), metrics.recall_at_full_precision(curve),
                      float(np.nanmedian(err)) if mapped.any() else float("nan"),
                      share(~mapped), share(mapped), match_ms, curve, lock_frames=tuple(lock.tolist()),
                      exit_frames=tuple(exits.tolist()) if threshold is not None else (),
                      metres=None if positions is None else metrics.metre_summary(
                          metrics.metre_errors(result.refs, truth, positions.coords, positions.geo), lost),
                      refs=result.refs, lost=lost, correct=correct[:, 0], scores=result.scores,
                      probabilities=result.probability,
                      answered_right=answered_right, mapped_right=mapped_right,
                      one_view=view, one_view_frames=distinct[0],
                      distinct_answered_right=distinct[1], distinct_mapped_right=distinct[2], why=why,
                      lost_why=reasons, target_precision=target_precision,
                      best_line_recall=metrics.recall_at_precision(curve, target_precision),
                      line_gap=metrics.line_gap(curve, answered_right, mapped_right), exact=exact, lead=lead)
