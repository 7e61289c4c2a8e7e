"""A confidence with one meaning in every mode: the probability that an answer is right, given its score,
measured on a labelled drive of the route (``evaluate --save-calibration``) and applied on the vehicle
(``localize --calibration``).

Each mode's score means something of its own (a cosine, a path margin, a trajectory's evidence), so no
threshold carries from one mode, or one route, to another. Calibration maps a mode's score to the share of
answers with that score that were right (within the evaluation's tolerance; an answer for a place not in the
map is wrong). Only answers given carry a confidence (a lost frame has none), so only they are fitted.
Two fits (``METHODS``): ``logistic`` (Platt scaling, p = 1 / (1 + exp(-(a * score + b))) with a >= 0, two
numbers, the default: it carries to another route better than a curve fitted to one route's every step,
docs/results.md, "Confidence across datasets") and ``isotonic`` (pool-adjacent-violators: the best
non-decreasing fit in least squares). Either way a higher score never means a lower confidence, and the
file holds the curve as points: between them the confidence is interpolated linearly, beyond them it is the
end value.

Beside the curve each mode carries its *line* on the drive: for each score, the share right among the drive's
answers scoring at least that (every frame's answer, lost or not: the answers ranked by score, as ``evaluate``
reads the best line) that the drive shows at 95% confidence (Wilson's lower bound: 57 answers all right show
0.955, 150 show 0.982). ``Curve.line(P)`` is the lowest score whose answers at least as high were right P of
the time so counted: ``localize --calibration FILE --target-precision P`` draws the lost line there, for any
mode, so a target precision means on a new front end what it meant on the labelled drive of the route, and a
drive too short to show it gives no line (``localize`` refuses the target) rather than the lowest score.
"""
from __future__ import annotations

import json
import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from vpr_edge.errors import InputError, VprError
from vpr_edge.files.atomic import atomic_output
from vpr_edge.files.npz import newer_schema

CALIBRATION_SCHEMA = 2     # 2: each mode's line
READ_SCHEMAS = (1, 2)      # 1: no line (a target precision refused with it)
METHODS = ("logistic", "isotonic")
DEFAULT_METHOD = "logistic"
_POINTS = 129                   # a logistic fit written as this many points, evenly spaced in log-odds
_LOGIT_SPAN = math.log(999)     # ... from confidence 0.001 to 0.999
LINE_Z = 1.645                  # the line's precision: Wilson's lower bound at 95% (one-sided)


def isotonic(scores: np.ndarray, correct: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pool-adjacent-violators over the answers sorted by score: -> (block scores (B,), confidence (B,))
    with confidence non-decreasing; each block's score is the mean of its answers' scores, its confidence
    their share of right answers."""
    order = np.argsort(scores, kind="stable")
    s, y = np.asarray(scores, np.float64)[order], np.asarray(correct, np.float64)[order]
    means: list[float] = []
    weights: list[float] = []
    sums: list[float] = []
    for value, score in zip(y, s):
        means.append(value)
        weights.append(1.0)
        sums.append(score)
        while len(means) > 1 and means[-2] > means[-1]:     # a violation: pool the last two blocks
            w = weights[-2] + weights[-1]
            means[-2] = (means[-2] * weights[-2] + means[-1] * weights[-1]) / w
            sums[-2] += sums[-1]
            weights[-2] = w
            del means[-1], weights[-1], sums[-1]
    w = np.asarray(weights)
    return np.asarray(sums) / w, np.asarray(means)


def wilson_lower(right: np.ndarray, n: np.ndarray, z: float = LINE_Z) -> np.ndarray:
    """Wilson's lower confidence bound on a share from ``right`` of ``n`` (arrays alike, n > 0): the share the
    counts show at the one-sided level of ``z`` standard normal deviations."""
    n = np.asarray(n, np.float64)
    p = np.asarray(right, np.float64) / n
    z2 = z * z
    return (p + z2 / (2 * n) - z * np.sqrt(p * (1 - p) / n + z2 / (4 * n * n))) / (1 + z2 / n)


def line_points(scores: np.ndarray, correct: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The answers' line: ``scores`` (Q,) and whether each answer was right (Q,) bool -> (thresholds (L,)
    ascending, precision (L,) increasing): the share right among the answers scoring at least each threshold,
    as its lower bound (``wilson_lower``), kept where it is higher than at every lower threshold (the only
    thresholds a line at some precision can sit on: the lowest one reaching it). No answer: both empty."""
    s = np.asarray(scores, np.float64)
    order = np.argsort(-s, kind="stable")
    s, ok = s[order], np.asarray(correct, bool)[order]
    if len(s) == 0:
        return np.zeros(0), np.zeros(0)
    last = np.r_[s[1:] != s[:-1], True]                      # the last answer of each run of tied scores
    precision = wilson_lower(np.cumsum(ok), np.arange(1, len(s) + 1))[last]
    thresholds = s[last]
    t, p = thresholds[::-1], precision[::-1]                 # ascending thresholds
    record = p > np.maximum.accumulate(np.r_[-1.0, p[:-1]])  # higher than at every lower threshold
    return t[record], p[record]


@dataclass(frozen=True)
class Curve:
    """One mode's calibration: confidence (B,) at block scores (B,), from ``n`` answers at ``tolerance``; its
    line on the drive (``line_points``: thresholds (L,) ascending, precision (L,); empty: a file without one)."""

    scores: np.ndarray
    confidence: np.ndarray
    n: int
    tolerance: int
    line_scores: np.ndarray = field(default_factory=lambda: np.zeros(0))
    line_precision: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def has_line(self) -> bool:
        """Whether the calibration holds the drive's line (schema 2)."""
        return len(self.line_scores) > 0

    def target_line(self) -> Callable[[float], float] | None:
        """``line`` where the calibration holds one, else None (a target precision then sets no line)."""
        return self.line if self.has_line else None

    def line(self, target: float) -> float:
        """The lowest score whose answers at least as high the drive shows right at least ``target`` of the
        time (``line_points``; inf where none does: every answer is then lost)."""
        reach = np.flatnonzero(self.line_precision >= target - 1e-12)
        return float(self.line_scores[reach[0]]) if len(reach) else math.inf

    def __call__(self, score: float) -> float:
        """The probability that an answer with this score is right, in [0, 1]."""
        return float(np.interp(score, self.scores, self.confidence))

    def of(self, scores: np.ndarray) -> np.ndarray:
        """``__call__`` over an array of scores (Q,) at once -> (Q,) float64."""
        return np.interp(np.asarray(scores, np.float64), self.scores, self.confidence)


def line_text(curve: Curve, target: float) -> str:
    """What ``curve``'s line at ``target`` is, in words: the score, or why there is none."""
    at = curve.line(target)
    if math.isinf(at):
        return f"none: these frames do not show {target:g} (every answer would be lost)"
    return f"score {at:.6g}"


def logistic(scores: np.ndarray, correct: np.ndarray, ridge: float = 1e-3,
             iterations: int = 100) -> tuple[float, float]:
    """Platt scaling over answers (Q,): (a, b) maximising the likelihood of ``correct`` under p(score) =
    1 / (1 + exp(-(a * score + b))), less ``ridge`` * a^2 / 2 (only so that answers split by the score stay
    finite), by Newton's method. Every answer right (or none): a = 0 and p the share right with one right
    and one wrong answer added (Laplace). a >= 0: where a higher score means worse, a = 0, b the log-odds."""
    s = np.asarray(scores, np.float64)
    ok = np.asarray(correct, bool)
    share = (ok.sum() + 1) / (len(ok) + 2)
    flat = (0.0, math.log(share / (1 - share)))
    if ok.all() or not ok.any():
        return flat
    x = np.column_stack([s, np.ones_like(s)])
    y = ok.astype(np.float64)
    odds = math.log(y.mean() / (1 - y.mean()))
    w = np.array([0.0, odds])
    penalty = np.diag([ridge, 0.0])
    for _ in range(iterations):
        p = 1 / (1 + np.exp(-np.clip(x @ w, -50, 50)))
        hess = (x * (p * (1 - p))[:, None]).T @ x + penalty + 1e-12 * np.eye(2)
        step = np.linalg.solve(hess, x.T @ (y - p) - penalty @ w)
        w += step
        if np.abs(step).max() < 1e-10:
            break
    if not (np.isfinite(w).all() and w[0] >= 0):
        return 0.0, odds
    return float(w[0]), float(w[1])


def fit(scores: np.ndarray, correct: np.ndarray, tolerance: int, answered: np.ndarray | None = None,
        method: str = DEFAULT_METHOD) -> Curve:
    """A mode's calibration from its answers' ``scores`` (Q,) and whether each was right (Q,) bool, fitted on
    the ``answered`` (Q,) bool ones (None: all; the rest are lost frames, which carry no confidence) by
    ``method`` (``METHODS``); its line (``line_points``) over every answer, lost or not. No answer given: the
    confidence is 0 everywhere."""
    if method not in METHODS:
        raise ValueError(f"calibration method {method!r}: expected one of {', '.join(METHODS)}")
    line = line_points(scores, correct)
    keep = np.ones(len(scores), bool) if answered is None else np.asarray(answered, bool)
    s, ok = np.asarray(scores, np.float64)[keep], np.asarray(correct, bool)[keep]
    if len(s) == 0:
        return Curve(np.zeros(1), np.zeros(1), 0, tolerance, *line)
    if method == "isotonic":
        x, y = isotonic(s, ok)
    else:
        a, b = logistic(s, ok)
        if a > 0:   # the logistic itself wherever it is between 0.001 and 0.999 (beyond: those values)
            x = (np.linspace(-_LOGIT_SPAN, _LOGIT_SPAN, _POINTS) - b) / a
        else:
            x = np.array([float(np.median(s))])
        y = 1 / (1 + np.exp(-np.clip(a * x + b, -50, 50)))
    return Curve(x, y, len(s), tolerance, *line)


def write(path: str | os.PathLike[str], curves: dict[str, Curve], source: str,
          method: str = DEFAULT_METHOD) -> None:
    """The calibration file: JSON with ``kind``, ``schema``, the fit's ``method`` (for the reader; the curve is
    all that is applied) and per mode its curve and its line (its thresholds exact: an answer at a threshold
    stays on its side), written atomically."""
    doc = {"kind": "calibration", "schema": CALIBRATION_SCHEMA, "source": source, "method": method,
           "modes": {name: {"scores": c.scores.round(6).tolist(), "confidence": c.confidence.round(6).tolist(),
                            "n": c.n, "tolerance": c.tolerance,
                            "line": {"scores": c.line_scores.tolist(), "precision": c.line_precision.tolist()}}
                     for name, c in curves.items()}}
    with atomic_output(path) as tmp:
        tmp.write_text(json.dumps(doc, indent=1) + "\n")


def _read(path: str | os.PathLike[str]) -> dict:
    """A calibration file's modes (JSON object per mode), its kind and schema checked (VprError naming it)."""
    try:
        with open(path) as f:
            doc = json.load(f)
    except (OSError, UnicodeDecodeError) as e:
        raise VprError(f"{path}: cannot read the calibration ({getattr(e, 'strerror', None) or e})") from None
    except json.JSONDecodeError as e:
        raise VprError(f"{path}: not a vpr-edge calibration (not JSON: {e})") from None
    if not isinstance(doc, dict) or doc.get("kind") != "calibration":
        raise InputError("{path}: not a vpr-edge calibration (evaluate {opt.save_calibration} writes one)", path=path)
    if doc.get("schema") not in READ_SCHEMAS:
        raise VprError(newer_schema(path, "calibration", doc.get("schema"), READ_SCHEMAS) or
                       f"{path}: calibration schema {doc.get('schema')} is not supported (this vpr-edge reads "
                       f"{', '.join(map(str, READ_SCHEMAS))})")
    modes = doc.get("modes")
    if not isinstance(modes, dict):
        raise VprError(f"{path}: not a vpr-edge calibration (no modes)")
    return modes


def load(path: str | os.PathLike[str], mode: str) -> Curve:
    """Mode ``mode``'s curve from a calibration file, every field checked (VprError naming the file)."""
    return _curve(path, _read(path), mode)


def load_held(path: str | os.PathLike[str], names: list[str]) -> tuple[dict[str, Curve], list[str]]:
    """The curves of the modes ``names`` that the file holds (each checked as ``load`` does), and every mode it
    holds; the file is read once."""
    modes = _read(path)
    return {name: _curve(path, modes, name) for name in names if name in modes}, list(modes)


def _curve(path: str | os.PathLike[str], modes: dict, mode: str) -> Curve:
    """Mode ``mode``'s curve out of a file's ``modes`` (``_read``), every field checked."""
    if mode not in modes:
        have = ", ".join(modes) or "none"
        raise InputError("{path}: no calibration for mode {mode} (it has {have}); run evaluate {opt.modes} {mode} "
                         "{opt.save_calibration}", path=path, mode=mode, have=have)
    m = modes[mode]
    try:
        x, y = np.asarray(m["scores"], np.float64), np.asarray(m["confidence"], np.float64)
        n, tolerance = int(m["n"]), int(m["tolerance"])
    except (KeyError, TypeError, ValueError):
        raise VprError(f"{path}: mode {mode}'s calibration is malformed (scores, confidence, n, tolerance)") from None
    ok = (x.ndim == 1 and x.shape == y.shape and len(x) > 0 and np.isfinite(x).all() and np.isfinite(y).all()
          and (np.diff(x) >= 0).all() and (np.diff(y) >= 0).all() and (y >= 0).all() and (y <= 1).all())
    if not ok or not math.isfinite(n):
        raise VprError(f"{path}: mode {mode}'s calibration is not a non-decreasing curve of confidences in [0, 1]")
    line = m.get("line", {"scores": [], "precision": []})
    try:
        t, p = np.asarray(line["scores"], np.float64), np.asarray(line["precision"], np.float64)
    except (KeyError, TypeError, ValueError):
        raise VprError(f"{path}: mode {mode}'s line is malformed (scores, precision)") from None
    if not (t.ndim == 1 and t.shape == p.shape and np.isfinite(t).all() and np.isfinite(p).all()
            and (np.diff(t) > 0).all() and (np.diff(p) > 0).all() and (p >= 0).all() and (p <= 1).all()):
        raise VprError(f"{path}: mode {mode}'s line is not thresholds rising with their precision in [0, 1]")
    return Curve(x, y, n, tolerance, t, p)
