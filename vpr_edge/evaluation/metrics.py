"""Place-recognition metrics over matcher results: recall@K, the precision-recall curve, AUC (thesis eq. 5.1),
AP (eq. 5.2), precision at full recall, recall at full precision, localisation error, and the delays of a stream
matcher at the route's transitions (lock-on after entering mapped places, lost after leaving them).

Ground truth is a padded int array ``truth`` (Q, T): per query its correct references, -1 as padding; a
query with no correct reference (a place not in the map) has a row of -1. A candidate is correct if it is
within ``tolerance`` references of one of its query's correct references.

The PR curve follows VPR practice (VPR_Tutorial's createPR): every query answers its best reference with a
score; at a threshold t the answers with score >= t are accepted; precision = correct accepted / accepted,
recall = correct accepted / queries whose place is in the map. An accepted answer for an unmapped place is a
false match. One point per distinct score (tied scores are accepted together).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def correct_candidates(ranked: np.ndarray, truth: np.ndarray, tolerance: int = 0,
                       drive: np.ndarray | None = None) -> np.ndarray:
    """(Q, k) candidates and (Q, T) padded truth -> (Q, k) bool: candidate within ``tolerance`` of a truth
    (and, with ``drive`` (R,), each reference's drive, in the truth's drive: neighbours in the map are not
    neighbours on the road across a drive's end)."""
    ranked = np.asarray(ranked)
    if ranked.ndim == 1:
        ranked = ranked[:, None]
    valid = truth >= 0                                                        # (Q, T)
    near = np.abs(ranked[:, :, None] - truth[:, None, :]) <= tolerance        # (Q, k, T)
    if drive is not None:
        near &= drive[np.maximum(ranked, 0)][:, :, None] == drive[np.maximum(truth, 0)][:, None, :]
    return (near & valid[:, None, :]).any(axis=2) & (ranked >= 0)


def recall_at_k(correct: np.ndarray, mapped: np.ndarray, k: int) -> float:
    """Share of mapped queries with a correct candidate among their first ``k`` (NaN if none is mapped)."""
    if not mapped.any():
        return float("nan")
    return float(correct[mapped, :k].any(axis=1).mean())


@dataclass(frozen=True)
class PRCurve:
    """Points of the precision-recall curve, one per distinct score threshold, thresholds descending."""

    precision: np.ndarray
    recall: np.ndarray
    thresholds: np.ndarray


def pr_curve(scores: np.ndarray, correct: np.ndarray, n_mapped: int) -> PRCurve:
    """Scores (Q,) of the answers, whether each is correct (Q,) bool, and the number of mapped queries."""
    scores = np.asarray(scores, np.float64)
    order = np.argsort(-scores, kind="stable")
    s, c = scores[order], np.asarray(correct, bool)[order]
    tp = np.cumsum(c)
    accepted = np.arange(1, len(s) + 1)
    last = np.r_[s[1:] != s[:-1], True]                   # the last index of each group of tied scores
    tp, accepted = tp[last], accepted[last]
    recall = tp / n_mapped if n_mapped else np.zeros(len(tp))
    return PRCurve(tp / accepted, recall, s[last])


def auc_trapezoid(curve: PRCurve) -> float:
    """Thesis eq. 5.1: sum over consecutive distinct recalls r_i < r_i+1 of
    (r_i+1 - r_i) * (min precision at r_i + max precision at r_i+1) / 2."""
    r = curve.recall
    levels = np.unique(r)
    if len(levels) < 2:
        return 0.0
    idx = np.searchsorted(levels, r)
    p_min = np.full(len(levels), np.inf)
    p_max = np.full(len(levels), -np.inf)
    np.minimum.at(p_min, idx, curve.precision)
    np.maximum.at(p_max, idx, curve.precision)
    return float(np.sum(np.diff(levels) * (p_min[:-1] + p_max[1:]) / 2.0))


def average_precision(curve: PRCurve) -> float:
    """Thesis eq. 5.2: AP = sum over thresholds of (R_n - R_n-1) * P_n, with R_0 = 0."""
    return float(np.sum(np.diff(np.r_[0.0, curve.recall]) * curve.precision))


def precision_at_full_recall(curve: PRCurve) -> float:
    """Precision at the first threshold reaching recall 1; 0 if recall 1 is never reached."""
    full = np.flatnonzero(curve.recall >= 1.0 - 1e-12)
    return float(curve.precision[full[0]]) if len(full) else 0.0


def recall_at_full_precision(curve: PRCurve) -> float:
    """Highest recall among thresholds with precision 1; 0 if the most confident answer is already wrong."""
    exact = curve.precision >= 1.0 - 1e-12
    return float(curve.recall[exact].max()) if exact.any() else 0.0


def recall_at_precision(curve: PRCurve, precision: float) -> float:
    """The best line the scores allow: the highest recall among thresholds whose precision is at least
    ``precision`` (the answers ranked by score); 0 if none reaches it."""
    ok = curve.precision >= precision - 1e-12
    return float(curve.recall[ok].max()) if ok.any() else 0.0


def line_gap(curve: PRCurve, delivered_precision: float, delivered_recall: float) -> float:
    """How much recall a lost line leaves on the table: the best line's recall at the precision the line
    delivered (``recall_at_precision``) minus the recall it delivered (NaN where nothing was answered)."""
    if not np.isfinite(delivered_precision):
        return float("nan")
    return recall_at_precision(curve, delivered_precision) - delivered_recall


def localisation_error(refs: np.ndarray, truth: np.ndarray, drive: np.ndarray | None = None) -> np.ndarray:
    """Per query: |answer - nearest correct reference| in references (Q,) float; NaN for unmapped queries
    (with ``drive`` (R,): infinite where no correct reference is in the answer's drive)."""
    valid = truth >= 0
    dist = np.where(valid, np.abs(np.asarray(refs)[:, None] - truth), np.iinfo(np.int64).max)
    if drive is not None:
        other = drive[np.asarray(refs)][:, None] != drive[np.maximum(truth, 0)]
        dist = np.where(valid & other, np.iinfo(np.int64).max, dist)
    err = dist.min(axis=1).astype(np.float64)
    err[~valid.any(axis=1)] = np.nan
    return err


def truth_middle(truth: np.ndarray) -> np.ndarray:
    """Per query, the middle of the places its truth lists (Q,) float (a truth of one place: that place;
    ±2 about a place: that place, but where a drive's end cuts the window); NaN for unmapped queries."""
    valid = truth >= 0
    lo = np.where(valid, truth, np.iinfo(np.int64).max).min(axis=1)
    hi = np.where(valid, truth, -1).max(axis=1)
    mid = (lo + hi) / 2.0
    mid[~valid.any(axis=1)] = np.nan
    return mid


def exact_and_lead(refs: np.ndarray, truth: np.ndarray, right: np.ndarray, lost: np.ndarray) -> tuple[float, float]:
    """Where answers fall against the truth's middle place (``truth_middle``): the share of mapped frames
    answered exactly there (not lost), and the lead, the mean of answer - middle over the right answers
    (frames; + ahead of the camera, - behind). ``right`` (Q,) bool: within tolerance; ``lost`` (Q,) bool."""
    mid = truth_middle(truth)
    mapped = ~np.isnan(mid)
    if not mapped.any():
        return float("nan"), float("nan")
    given = mapped & ~lost
    exact = float((given & (np.asarray(refs, np.float64) == mid)).sum() / mapped.sum())
    near = given & right
    lead = float((np.asarray(refs, np.float64)[near] - mid[near]).mean()) if near.any() else float("nan")
    return exact, lead


METRE_RADII: tuple[float, ...] = (5.0, 10.0, 25.0)


def metre_errors(refs: np.ndarray, truth: np.ndarray, coords: np.ndarray, geo: bool) -> np.ndarray:
    """Per query, metres from the answered reference's position to the nearest correct reference's
    (``coords`` (R, 2), x/y metres or lat/lon degrees) -> (Q,) float, NaN for unmapped queries."""
    from vpr_edge.positions import paired_distances

    out = np.full(len(refs), np.nan)
    for col in range(truth.shape[1]):
        t = truth[:, col]
        ok = t >= 0
        d = paired_distances(coords[refs[ok]], coords[t[ok]], geo)
        out[ok] = np.fmin(out[ok], d)
    return out


def metre_summary(errors: np.ndarray, lost: np.ndarray) -> dict[str, float]:
    """Over the mapped queries (finite ``errors``): the median and 90th percentile of the error in metres of
    the answers not reported lost, and the share of mapped queries answered (not lost) within each of
    ``METRE_RADII`` metres (a lost frame counts as not within)."""
    mapped = np.isfinite(errors)
    answered = errors[mapped & ~lost]
    nan = float("nan")
    out = {"median_m": float(np.median(answered)) if answered.size else nan,
           "p90_m": float(np.percentile(answered, 90)) if answered.size else nan}
    for r in METRE_RADII:
        out[f"within_{r:g}m"] = float(((errors <= r) & ~lost)[mapped].mean()) if mapped.any() else nan
    return out


def runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """The runs of True in ``mask`` (Q,) bool as [start, stop) frame pairs, in order."""
    edges = np.flatnonzero(np.diff(np.concatenate([[False], np.asarray(mask, bool), [False]]).astype(np.int8)))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist()))


def first_event_delays(region: np.ndarray, event: np.ndarray) -> np.ndarray:
    """For each run of ``region`` (Q,) bool: frames from its first frame to the first frame in it where
    ``event`` (Q,) bool holds (0 = at once) -> (number of runs,) float; NaN where it never holds in the run."""
    out = []
    for a, b in runs(region):
        hit = np.flatnonzero(event[a:b])
        out.append(float(hit[0]) if len(hit) else float("nan"))
    return np.asarray(out, np.float64)


def transition_delays(mapped: np.ndarray, found: np.ndarray, lost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A stream's behaviour where the route enters and leaves the map, per frame (Q,) bool: ``mapped`` (the
    frame's place is in the map), ``found`` (a confident, correct answer), ``lost`` (reported lost) ->
    (lock-on delays: per run of mapped frames, including one at the stream's start, frames until the first
    found one; exit delays: per run of unmapped frames, frames until the first lost one), NaN where it never
    happened within the run."""
    mapped = np.asarray(mapped, bool)
    return first_event_delays(mapped, np.asarray(found, bool)), first_event_delays(~mapped, np.asarray(lost, bool))


def answered_shares(correct: np.ndarray, lost: np.ndarray, mapped: np.ndarray) -> tuple[float, float]:
    """(share of answered frames that are right, share of mapped frames answered right): the first is the
    precision a vehicle sees at the lost threshold (an answer for an unmapped place is wrong), the second its
    recall. Inputs (Q,) bool; NaN where no frame is answered / mapped."""
    answered = ~lost
    right = correct & answered
    return (float(right.sum() / answered.sum()) if answered.any() else float("nan"),
            float((right & mapped).sum() / mapped.sum()) if mapped.any() else float("nan"))


def reliability(confidence: np.ndarray, correct: np.ndarray, bins: int = 10) -> tuple[float, list[dict]]:
    """Expected calibration error and the reliability table of ``confidence`` (Q,) in [0, 1] against
    ``correct`` (Q,) bool: ``bins`` equal-width bins of confidence (the last closed); per non-empty bin its
    range, count, mean confidence and share right; ECE = sum over bins of count / Q * |share right - mean
    confidence|."""
    conf = np.clip(np.asarray(confidence, np.float64), 0.0, 1.0)
    ok = np.asarray(correct, bool)
    if len(conf) == 0:
        return float("nan"), []
    idx = np.minimum((conf * bins).astype(int), bins - 1)
    table, ece = [], 0.0
    for b in range(bins):
        sel = idx == b
        n = int(sel.sum())
        if n:
            mean_conf, share = float(conf[sel].mean()), float(ok[sel].mean())
            ece += n / len(conf) * abs(share - mean_conf)
            table.append({"from": b / bins, "to": (b + 1) / bins, "n": n, "confidence": round(mean_conf, 6),
                          "right": round(share, 6)})
    return float(ece), table


def brier(confidence: np.ndarray, correct: np.ndarray) -> float:
    """Brier score of ``confidence`` (Q,) in [0, 1] against ``correct`` (Q,) bool: the mean squared difference
    (0 = sure and right every time; a constant at the share right scores that share times its complement).
    Unlike the ECE it rewards a confidence that tells right answers from wrong ones. NaN for no answers."""
    conf = np.clip(np.asarray(confidence, np.float64), 0.0, 1.0)
    return float(np.mean((conf - np.asarray(correct, np.float64)) ** 2)) if len(conf) else float("nan")
