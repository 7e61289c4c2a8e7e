"""The stream matcher's verdict: the probability that its answer is right, from a model of "not this place"
estimated on the map and the stream alone (no labels, no front-end constant), so that one line (the target
precision) means the same on every front end, route and camera.

Two questions, two factors, ``probability = place * view``, and a line on the answers' precision:

* **Does the answer's trajectory stand out of the trajectories that are not this place?** The trajectory
  scores H of places far from the answer are the null: H of a wrong place is a decayed sum of a frame's
  normalised similarities minus a bias, a reflected random walk with negative drift, whose scores have an
  exponential upper tail (Lindley). Its scale ``beta`` is read from the spacings of the highest rival peaks
  (one per block of the route, so that one cluster counts once): for an exponential tail the normalised
  spacings i * (x_(i) - x_(i+1)) are independent draws of mean ``beta`` (Renyi), pooled over the recent
  frames (``TailScale``). A rival peak x then explains the answer's score b with weight exp(-(b - x) / beta),
  and ``trajectory_probability`` = 1 / (1 + sum over rivals of those weights, ``rival_weight``): a softmax over the hypotheses
  with the null's own temperature. Off the map, the best is the top of the null and the gap to the next is an
  exponential draw of mean beta, so a line at P is passed by at most about 1 - P of such frames (a constant
  false-alarm rate), whatever the similarities' scale.
  The places next to the answer (within the rival window) are hypotheses too: a trajectory a few places off
  (a lag, a speed change) is the commonest confident wrong answer. Each weighs exp(-(best - H) / scale) with
  ``PLACE_SCALE`` of beta, and ``place_probability`` is the share of all the weight (near places and rivals)
  on the places within ``ANSWER_SLACK`` of the answer: the probability that an answer there is right.
* **Does this frame still show the answer's place?** A trajectory remembers ~1/(1 - decay) frames, so it
  says late that the vehicle left the map; the frame says so at once. ``view_quantile`` is the share of the
  frame's references that look at least as much like it as the answer does (uniform over [0, 1] where the
  answer is not its place). Where it is, the quantile leans to 0: modelled as Beta(a, 1), whose ``a`` is
  learned from the stream's own frames whose trajectory stands out (``ViewFilter``; 1 = a front end that tells
  nothing, near 0 = a sharp one). A two-state filter (on the answer's place / not) turns the likelihood
  ratio a * q^(a - 1) into the probability of being on it; leaving and entering have fixed prior rates
  (``LEAVE``, ``ENTER``: constants, not fitted to a route).

  The view is read from the frame's z-scores less each place's mean z over the stream's last few moving
  frames (``RecentViews``): a place that resembles every recent frame (a hub of this stream: imagery of
  somewhere else that happens to look like one reference more than the rest) is no evidence, while the true
  place stands out only as the vehicle passes it. Without it, a map answered imagery of a place it does not
  hold whenever one reference looked most like all of it (docs/results.md, "The line on any front end").

* **Is the stream on the map at all?** (With the ``decoy`` parameter, ``stream-decoy``'s; ``road.RoadMatcher``
  runs it, for ``stream`` too.) The same trajectories run over the map's
  references in reverse order (a *decoy*: a vehicle drives its route forwards), so each frame's best decoy
  trajectory is a draw of "the best trajectory where the answer is not the place" from the same front end,
  frame and hubs. Imagery of somewhere else scores alike forwards and backwards; a mapped stream's true
  trajectory scores far above its decoy. ``DecoyGate`` opens while the recent mean of (best - decoy best) is
  at least ``DECOY_LINE`` spreads of the recent decoy bests; closed, the score is 0 (the frame is lost). It
  learns only from frames that tell forwards from backwards: not a standing camera (the state stands still
  too) nor a best, forwards or reversed, where the map shows one view (a trajectory fits a station's run alike
  both ways, and a reversed best there climbed as high as the true one).

* **Where is the line?** A line on each answer's own probability asks every answer to be P sure, so the
  answers given are right far more often than P. ``line_score`` scores an answer by the precision expected of
  the stream's recent answers at least as sure (their mean probability: a Bayesian false discovery rate
  line), so that a line at P delivers about P, for answers at least ``ANSWER_FLOOR`` sure: a vehicle acts on
  each answer, and after a long sure stretch that mean stays high while the first frames off the map come in.

The model's constants are named once, in ``constants``; docs/decisions.md says what they were chosen on.
"""
from __future__ import annotations

import math
from collections import deque

import numpy as np

from vpr_edge.matchers.constants import (ANSWER_FLOOR, DECOY_LINE, DECOY_MEMORY, DECOY_SPREAD, DECOY_WARM, ENTER,
                                         HUB_MEMORY, HUB_PRIOR, LEAVE, TAIL_MEMORY, TAIL_PEAKS, VIEW_MEMORY,
                                         VIEW_PRIOR, VIEW_PRIOR_FRAMES, VIEW_RANGE)
from vpr_edge.matchers.route import Intervals, inside

def block_peaks(values: np.ndarray, where: np.ndarray | None, width: int,
                exclude: Intervals) -> tuple[np.ndarray, np.ndarray]:
    """The per-place trajectory scores ``values`` (n,) at the places ``where`` (n,) sorted (None: 0..n-1) ->
    (peaks, blocks): the highest score in each block of ``width`` places along the map (block = place //
    width) that holds a place outside the intervals ``exclude`` ([lo, hi) places; those are left out), and
    the blocks' numbers, both (blocks,) in block order."""
    values = np.asarray(values, np.float64)
    width = max(1, int(width))
    if where is None and len(exclude) <= 1:   # the whole route less one interval: two runs of whole blocks
        lo, hi = exclude[0] if exclude else (0, 0)
        runs = [(0, lo), (hi, len(values))] if hi > lo else [(0, len(values))]
        out_v, out_b = [], []
        for a, b in runs:
            if b <= a:
                continue
            first = np.arange(a // width, (b - 1) // width + 1, dtype=np.int64)
            starts = np.maximum(first * width, a) - a
            out_v.append(np.maximum.reduceat(values[a:b], starts))
            out_b.append(first)
        if not out_v:
            return np.zeros(0), np.zeros(0, np.int64)
        if len(out_v) == 1:
            return out_v[0], out_b[0]
        if out_b[0][-1] == out_b[1][0]:   # the interval left out lies inside one block: that block counts once
            out_v[1][0] = max(out_v[1][0], out_v[0][-1])
            out_v[0], out_b[0] = out_v[0][:-1], out_b[0][:-1]
        return np.concatenate(out_v), np.concatenate(out_b)
    places = np.arange(len(values)) if where is None else np.asarray(where, np.int64)
    keep = ~inside(places, exclude)
    if not keep.any():
        return np.zeros(0), np.zeros(0, np.int64)
    v, block = values[keep], places[keep] // width
    change = np.empty(len(block), bool)
    change[0] = True
    np.not_equal(block[1:], block[:-1], out=change[1:])
    starts = np.flatnonzero(change)
    return np.maximum.reduceat(v, starts), block[starts]


def spacings(peaks: np.ndarray, top: int = TAIL_PEAKS) -> np.ndarray:
    """The normalised spacings i * (x_(i) - x_(i+1)), i = 1.., of the ``top`` highest positive ``peaks``
    (sorted down): for an exponential tail, independent draws whose mean is its scale. (k,) with k one less
    than the positive peaks used (0 if fewer than two)."""
    x = np.asarray(peaks, np.float64)
    x = x[x > 0]
    if len(x) > top:   # the top ones only: a partition, then a sort of those
        x = np.partition(x, len(x) - top)[len(x) - top:]
    if len(x) < 2:
        return np.zeros(0)
    x.sort()
    return np.arange(1, len(x)) * np.diff(x)[::-1]


class TailScale:
    """The null's tail scale ``beta``, pooled over frames: each frame's ``spacings`` added with the past's
    weight decayed by 1 - 1 / ``memory``. ``value`` is None until a spacing has been seen."""

    def __init__(self, memory: float = TAIL_MEMORY) -> None:
        self.keep = 1.0 - 1.0 / memory
        self.total, self.count = 0.0, 0.0

    def add(self, gaps: np.ndarray) -> None:
        self.total = self.keep * self.total + float(np.sum(gaps))
        self.count = self.keep * self.count + len(gaps)

    @property
    def value(self) -> float | None:
        if self.count <= 0 or self.total <= 0:
            return None
        return self.total / self.count


def rival_weight(best: float, rivals: np.ndarray, beta: float | None) -> float:
    """Sum over rival peaks of exp(-(best - rival) / beta): how much the rivals explain the answer's score
    (``beta`` None: the scale is not known yet, the rivals explain everything: inf)."""
    if beta is None:
        return math.inf
    r = np.asarray(rivals, np.float64)
    return float(np.exp(np.minimum((r - best) / beta, 50.0)).sum())


def trajectory_probability(weight: float) -> float:
    """The probability that the best trajectory is the place rather than one of the rivals whose
    ``rival_weight`` is ``weight``: 1 / (1 + weight) (0 for an infinite weight)."""
    return 0.0 if math.isinf(weight) else 1.0 / (1.0 + weight)


def near_values(values: np.ndarray, where: np.ndarray | None, near: Intervals) -> tuple[np.ndarray, np.ndarray]:
    """The per-place scores ``values`` (n,) of the places ``where`` (sorted; None: 0..n-1) that lie in the
    intervals ``near`` ([lo, hi) places) -> (their places, their values), both (m,) in place order."""
    if where is None:
        places = np.concatenate([np.arange(lo, hi) for lo, hi in near]) if near else np.zeros(0, np.int64)
        return places, np.asarray(values)[places]
    keep = inside(where, near)
    return np.asarray(where, np.int64)[keep], np.asarray(values)[keep]


def place_probability(best: float, places: np.ndarray, values: np.ndarray, right: Intervals, rivals: float,
                      scale: float | None) -> float:
    """The probability that the place lies within ``right`` (the places an answer there counts as right
    for): a softmax over the hypotheses, each place near the answer (``places``, with their best trajectory
    scores ``values``; the answer's own among them, at ``best``) of weight exp((value - best) / ``scale``),
    and the rivals far away of summed weight ``rivals`` (``rival_weight``). ``scale`` None: nothing known
    yet, 0. With no place near but the answer, 1 / (1 + rivals): ``trajectory_probability``."""
    if scale is None or math.isinf(rivals):
        return 0.0
    w = np.exp(np.minimum((np.asarray(values, np.float64) - best) / scale, 50.0))
    return float(w[inside(places, right)].sum() / (w.sum() + rivals))


def expected_precision(probability: float, recent: np.ndarray) -> float:
    """The precision expected of the answers at least as sure as this one (``probability``) among the
    ``recent`` probabilities (this one's included): their mean. A line at P on it gives answers whose mean
    probability of being right, so whose expected precision, is at least P (a Bayesian false discovery rate
    line), where a line on each answer's own probability asks every answer to be P sure."""
    r = np.asarray(recent, np.float64)
    sure = r[r >= probability]
    return float(sure.mean()) if len(sure) else probability


def line_score(probability: float, recent: np.ndarray, floor: float = ANSWER_FLOOR) -> float:
    """The score a target-precision line is drawn on: for an answer at least ``floor`` sure, the precision
    expected of the ``recent`` answers at least as sure (``expected_precision``); for a less sure one, its own
    ``probability`` (below any line above ``floor``: never given)."""
    return expected_precision(probability, recent) if probability >= floor else probability


def local_best(part: np.ndarray, where: np.ndarray | None, exclude: Intervals) -> np.ndarray:
    """A frame's similarities ``part`` (n,) to the places ``where`` (sorted; None: 0..n-1), each replaced by
    the best of it and its neighbours in ``part`` (as the answer's view is read), less the places in the
    intervals ``exclude`` ([lo, hi)): the frame's views of places that are not the answer's, (m,)."""
    part = np.asarray(part, np.float64)
    best = part.copy()
    if len(part) > 1:
        np.maximum(best[1:], part[:-1], out=best[1:])
        np.maximum(best[:-1], part[1:], out=best[:-1])
    if where is None:   # the whole route: the intervals cut out by slices
        keep = np.ones(len(part), bool)
        for lo, hi in exclude:
            keep[lo:hi] = False
        return best[keep]
    return best[~inside(np.asarray(where, np.int64), exclude)]


def view_quantile(null: np.ndarray, here: float) -> float:
    """The share of the views ``null`` (``local_best``) at least as alike the frame as ``here`` (the
    answer's), counting the answer's own: in (0, 1]; uniform where the answer is not the frame's place."""
    null = np.asarray(null)
    return (float(np.count_nonzero(null >= here)) + 1.0) / (len(null) + 1.0)


class RecentViews:
    """Each place's mean z-score over the stream's recent frames that saw it (``memory`` frames, an
    exponential memory per sighting), shrunk towards 0 by a prior of ``prior`` sightings against every sighting
    of the place so far (a place seen by every frame is, after a few, corrected in full: shrinking by the
    memory's weight alone would leave 1 / (memory + 1) of any z-score standing). ``corrected(z, places)``: the
    frame's z-scores (n,) of ``places`` (n,) less those means, as they stood before the frame; ``add(z,
    places)``: the frame joins the means; ``read(z, places, learn)``: both, the frame joining only where
    ``learn``."""

    def __init__(self, n_places: int, memory: float = HUB_MEMORY, prior: float = HUB_PRIOR) -> None:
        self.keep, self.prior = 1.0 - 1.0 / memory, prior
        self.mean, self.weight = np.zeros(n_places), np.zeros(n_places)
        self.seen = np.zeros(n_places)   # sightings of each place so far (not forgotten)

    def corrected(self, z: np.ndarray, places: np.ndarray | slice) -> np.ndarray:
        n = self.seen[places]
        return np.asarray(z, np.float64) - self.mean[places] * (n / (n + self.prior))

    def add(self, z: np.ndarray, places: np.ndarray | slice) -> None:
        w = self.weight[places] * self.keep + 1.0
        self.weight[places] = w
        self.mean[places] += (np.asarray(z, np.float64) - self.mean[places]) / w
        self.seen[places] += 1.0

    def read(self, z: np.ndarray, places: np.ndarray | slice, learn: bool) -> np.ndarray:
        """``corrected(z, places)``, then the frame joins the means if ``learn``."""
        views = self.corrected(z, places)
        if learn:
            self.add(z, places)
        return views


class ViewFilter:
    """The probability that the frames still show the answer's place, from their ``view_quantile``s (see the
    module docstring). ``update(q, teach)``: one frame's quantile; ``teach``: its trajectory stands out, so
    its quantile is a sample of the on-place distribution (learns ``a``). ``p``: the current probability."""

    def __init__(self) -> None:
        self.keep = 1.0 - 1.0 / VIEW_MEMORY
        self.log_sum, self.frames = VIEW_PRIOR_FRAMES / VIEW_PRIOR, VIEW_PRIOR_FRAMES   # sum of -log q, count
        self.p = ENTER

    @property
    def a(self) -> float:
        """The on-place Beta(a, 1) shape: frames / sum of -log q (its maximum-likelihood value), in range."""
        lo, hi = VIEW_RANGE
        return min(hi, max(lo, self.frames / self.log_sum))

    def ratio(self, q: float) -> float:
        """Likelihood ratio on-place / off-place of a frame with quantile ``q``."""
        a = self.a
        return a * max(q, 1e-12) ** (a - 1.0)

    def update(self, q: float, teach: bool) -> float:
        prior = self.p * (1.0 - LEAVE) + (1.0 - self.p) * ENTER
        lr = self.ratio(q)
        self.p = prior * lr / (prior * lr + 1.0 - prior)
        if teach:
            self.log_sum = self.keep * self.log_sum + -math.log(max(q, 1e-12))
            self.frames = self.keep * self.frames + 1.0
        return self.p


class DecoyGate:
    """Whether the stream shows the map at all, from each frame's best trajectory score and its decoy's (the
    best over the map's references in reverse order; module docstring): open while the exponential mean over
    ``memory`` frames of (best - decoy) is at least ``line`` times the standard deviation of the last
    ``spread`` decoy bests, once ``warm`` frames have told (``update``'s ``telling``). ``update(best, decoy,
    telling)`` -> open."""

    def __init__(self, memory: float = DECOY_MEMORY, line: float = DECOY_LINE, spread: int = DECOY_SPREAD,
                 warm: int = DECOY_WARM) -> None:
        self.keep, self.line, self.warm = 1.0 - 1.0 / memory, line, warm
        self.total, self.weight = 0.0, 0.0
        self.decoys: deque[float] = deque(maxlen=spread)
        self.open = False

    def update(self, best: float, decoy: float, telling: bool = True) -> bool:
        """One frame's best trajectory score and its decoy's -> open. A frame that does not tell forwards from
        backwards (``telling`` False: a standing camera, or a best where the map shows one view, where a
        trajectory fits alike both ways) leaves the gate as it was."""
        if telling:
            self.total = self.keep * self.total + (best - decoy)
            self.weight = self.keep * self.weight + 1.0
            self.decoys.append(decoy)
            self.open = len(self.decoys) >= self.warm and \
                self.total / self.weight >= self.line * float(np.std(self.decoys))
        return self.open
