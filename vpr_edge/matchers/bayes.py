"""The ``stream-filter`` matcher: a Bayes filter over (place along the route, speed), plus one off-map state.

The hidden state of a frame is where the camera is on the map and how fast it moves along it, in places a
frame (0..``vmax``), or that it is somewhere the map does not hold (*off-map*). Each frame:

1. **Predict** (the motion model). A speed changes by one step with probability ``speed_change`` each way;
   then the camera moves on by its speed. Mass that runs past a drive's last place leaves the map; a drive
   joined to another (``route.RouteGraph``'s junctions) passes a share ``JOIN`` of its junction places' mass
   on to the other drive. Every frame, ``leave`` of the on-map mass moves off the map, ``jump`` of it to a
   place anywhere on the map (a re-localisation), and ``enter`` of the off-map mass comes back onto the map
   at any place.
2. **Correct** (the likelihood of the frame's similarity row). The row is read on its own scale: robust
   z-scores ``z = (s - median) / spread`` (spread from the inter-quartile range), less each place's running
   mean over this stream's moving frames (``hub_memory``: a place that looks like every frame is no
   evidence; a frame joins those means ``HUB_DELAY`` frames late). The likelihood ratio of "the camera is
   at place p" against "off the map" is

       LR(p) = exp(beta * z_p - beta^2 / 2)

   with the row's bulk a standard normal null (most of a row is "not this place") and the true place's
   z-score normal about ``beta``; the off-map state's likelihood is 1. A row says "on the map" where a
   place stands out of it, and "here" where that place lies where the motion model predicted it. ``beta``
   is the stream's own: the running mean of the z-score at the answered place, weighted by the answer's
   confidence (a prior of ``SCALE_PRIOR`` for ``SCALE_PRIOR_FRAMES`` frames), times ``temper`` (< 1:
   neighbouring frames and places see alike, so a frame is worth less than an independent observation).
   A front end whose cosines lie in 0.9-1.0 and one whose cosines spread over 0-1 are read alike.
3. The **motion cue** (``motion.MotionCue``) observes the speed: a frame whose cue reaches ``still`` (its
   view is nearly the last moving frame's) weighs speed 0 by the cue and the moving speeds by 1 - cue
   (never below ``CUE_FLOOR``), and counts 1 - cue of its view's evidence (a view seen again says
   nothing new). Where the map's own drive stood (``route``) the frame is read as motion.

The answer is the place of the posterior's mode (summed over speeds), its **confidence** the posterior mass
within ``tolerance`` places of it along the route: the probability that the answer is within ``tolerance``
of the true place. A frame is lost below the line (``--target-precision``); ``why`` says what holds the
missing mass: ``off-map`` (the off-map state), ``ambiguous`` (another stretch of the route) or ``settling``
(spread thinly: not converged yet).

State: (``vmax`` + 1, R) float64, the hub means and ``HUB_DELAY`` z-score rows, whatever the stream's
length; a frame costs O(vmax² R). Every frame reads every place (no local search, no index).
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, fields, replace

import numpy as np

from vpr_edge.matchers.base import AMBIGUOUS, OFF_MAP, SETTLING
from vpr_edge.matchers.constants import (CUE_FLOOR, HUB_DELAY, JOIN, MIN_SPREAD, SCALE_BOUNDS, SCALE_PRIOR, SCALE_PRIOR_FRAMES,
                                         START_OFF)
from vpr_edge.matchers.motion import stands
from vpr_edge.matchers.route import RouteGraph, places



@dataclass(frozen=True)
class FilterConfig:
    """The filter's parameters (``params.STREAM_FILTER``: their defaults and meanings). ``still_memory`` and
    ``seek_frames`` are read where the motion cue and the index query are made."""

    vmax: int
    speed_change: float
    leave: float
    enter: float
    jump: float
    temper: float
    hub_memory: float
    scale_memory: float
    tolerance: int
    rival_window: int
    still: float
    still_memory: int

    def __post_init__(self) -> None:
        for name in ("speed_change", "leave", "enter", "jump"):
            if not 0.0 <= getattr(self, name) < 0.5:
                raise ValueError(f"{name} must lie in [0, 0.5), got {getattr(self, name)}")
        if self.vmax < 0 or self.tolerance < 0 or self.rival_window < 0:
            raise ValueError(f"need vmax, tolerance and rival_window >= 0 (got {self.vmax}, {self.tolerance}, "
                             f"{self.rival_window})")
        if not 0.0 < self.temper <= 4.0:
            raise ValueError(f"temper must lie in (0, 4], got {self.temper}")
        if self.hub_memory < 0 or self.scale_memory < 1:
            raise ValueError(f"need hub_memory >= 0 (0: off) and scale_memory >= 1 (got {self.hub_memory}, "
                             f"{self.scale_memory})")
        if not 0.0 <= self.still <= 1.0:
            raise ValueError(f"still must be in [0, 1] (0: no motion cue), got {self.still}")

    @classmethod
    def of(cls, params: dict) -> "FilterConfig":
        """The configuration from a parameter dict; keys it does not hold are ignored."""
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in params.items() if k in names})


def speed_kernel(n_speeds: int, change: float) -> np.ndarray:
    """(V, V) row-stochastic: from speed v to v' (one step either way with probability ``change``; at the
    ends the step that would leave the range stays)."""
    k = np.zeros((n_speeds, n_speeds))
    for v in range(n_speeds):
        for w in (v - 1, v + 1):
            k[v, min(max(w, 0), n_speeds - 1)] += change
        k[v, v] += 1.0 - 2.0 * change
    return k


def robust_z(row: np.ndarray, sample: np.ndarray | None = None) -> np.ndarray:
    """A similarity row (n,) -> its robust z-scores: less the median, over the spread (inter-quartile range /
    1.349, the standard deviation of a normal bulk), both read on ``sample`` (values; None: the row)."""
    ref = row if sample is None else sample
    q25, q50, q75 = np.percentile(ref, (25, 50, 75))
    return (row - q50) / max((q75 - q25) / 1.349, MIN_SPREAD)


def likelihood(z: np.ndarray, beta: float) -> tuple[np.ndarray, float]:
    """Likelihood ratios of "the camera is at place p" against "off the map", up to one factor: (lr (n,), the
    off-map state's likelihood on the same scale). With the row's bulk a standard normal null and the true
    place's z-score normal about ``beta``, the ratio is exp(beta * z - beta^2 / 2); scaled so that the
    largest of the lot is 1 (no overflow)."""
    ll = beta * z - 0.5 * beta * beta
    top = max(float(ll.max()), 0.0)
    return np.exp(ll - top), math.exp(-top)


class Transitions:
    """The motion model on a route graph: ``predict(b, off)`` moves the on-map mass ``b`` (V, R) and the
    off-map mass one frame on (module docstring, step 1)."""

    def __init__(self, graph: RouteGraph, config: FilterConfig) -> None:
        self.graph, self.config = graph, config
        self.n_speeds = config.vmax + 1
        self.kernel = speed_kernel(self.n_speeds, config.speed_change)
        self.cut = graph.cuts(1, self.n_speeds)   # (v, place): came from another drive
        self.ends = graph.ends

    def entry(self) -> np.ndarray:
        """Where mass coming onto the map lands: (V, R), every place and speed alike, summing to 1."""
        return np.full((self.n_speeds, self.graph.n_refs), 1.0 / (self.n_speeds * self.graph.n_refs))

    def predict(self, b: np.ndarray, off: float) -> tuple[np.ndarray, float]:
        """(V, R) on-map mass and the off-map mass -> the same one frame on (sums kept)."""
        c = self.config
        b = self.kernel.T @ b
        ran = 0.0
        moved = np.empty_like(b)
        moved[0] = b[0]
        r = b.shape[1]
        for v in range(1, self.n_speeds):
            if v >= r:
                moved[v] = 0.0
                ran += float(b[v].sum())
                continue
            moved[v, v:] = b[v, :-v]
            moved[v, :v] = 0.0
            ran += float(b[v, r - v:].sum())
        cv, cc = self.cut
        if len(cc):
            ran += float(moved[cv, cc].sum())
            moved[cv, cc] = 0.0
        for sources, targets in self.graph.junctions:
            share = moved[:, sources].sum(axis=1) * JOIN
            moved[:, sources] *= 1.0 - JOIN
            moved[:, targets] += (share / len(targets))[:, None]
        on = float(moved.sum())
        out = moved * (1.0 - c.leave - c.jump)
        out += (c.jump * on + c.enter * off) * self.entry()
        return out, off * (1.0 - c.enter) + c.leave * on + ran


class BayesFilter:
    """The online ``stream-filter`` matcher (module docstring) over ``n_refs`` places of ``graph``'s route."""

    searches_locally = False

    def __init__(self, n_refs: int, config: FilterConfig, graph: RouteGraph | None = None,
                 route: np.ndarray | None = None) -> None:
        if n_refs < 1:
            raise ValueError("need at least one reference")
        self.n_refs, self.config = n_refs, config
        self.graph = RouteGraph.line(n_refs) if graph is None else graph
        if self.graph.n_refs != n_refs:
            raise ValueError(f"route graph of {self.graph.n_refs} references for {n_refs}")
        self.route = None if route is None else np.asarray(route, bool)
        self.moves = Transitions(self.graph, config)
        self.reset()

    def reset(self) -> None:
        """Forget the stream: the prior (``START_OFF`` off the map, the rest anywhere on it)."""
        self.b = self.moves.entry() * (1.0 - START_OFF)
        self.off = START_OFF
        self._hub = np.zeros(self.n_refs)
        self._seen = 0.0                      # moving frames in the hub means (an exponential count)
        self._delay: deque[np.ndarray] = deque()   # the last HUB_DELAY frames' z-scores, not in the means yet
        self._scale = [0.0, 0.0]              # confidence-weighted sum of the answer's z, and of the weights
        self._mode, self._conf, self._why = 0, 0.0, SETTLING
        self._marginal = self.b.sum(axis=0)

    # --- the contract (``base.OnlineMatcher``) --------------------------------------------------------------
    def wanted(self) -> None:
        return None

    def position(self) -> None:
        return None

    def probability(self) -> float:
        """The probability that the last answer lies within ``tolerance`` of the true place."""
        return self._conf

    def why(self) -> str:
        """What holds the probability the last answer is not right (``base.FILTER_REASONS``)."""
        return self._why

    def ranking(self) -> np.ndarray:
        """The posterior probability of each place (R,), summed over speeds."""
        return self._marginal

    @property
    def off_map(self) -> float:
        """The posterior probability that the camera is off the map."""
        return self.off

    @property
    def beta(self) -> float:
        """The likelihood's scale now (module docstring)."""
        s, w = self._scale
        mean = (s + SCALE_PRIOR * SCALE_PRIOR_FRAMES) / (w + SCALE_PRIOR_FRAMES)
        return self.config.temper * float(np.clip(mean, *SCALE_BOUNDS))

    def update(self, sim_row: np.ndarray, refs: np.ndarray | None = None,
               still: float | None = None) -> tuple[int, float]:
        """The frame's similarities to every place (R,) and its motion cue -> (answer, confidence)."""
        s = np.asarray(sim_row, np.float64)
        if refs is not None or s.shape != (self.n_refs,):
            raise ValueError(f"similarity row must have shape ({self.n_refs},), got {s.shape}")
        new = self._novelty(still)
        z = self._evidence(s, new)
        self.b, self.off = self.moves.predict(self.b, self.off)
        if still is not None and self.config.still:   # the cue observes the speed: 0 where the view is the same
            self.b[0] *= max(1.0 - new, CUE_FLOOR)
            self.b[1:] *= max(new, CUE_FLOOR)
            self.off *= max(new, CUE_FLOOR) * (1.0 - 1.0 / self.moves.n_speeds) + max(1.0 - new, CUE_FLOOR) / self.moves.n_speeds
        lr, off_lr = likelihood(z, new * self.beta)
        self.b *= lr[None, :]
        self.off *= off_lr
        total = float(self.b.sum()) + self.off
        if not math.isfinite(total) or total <= 0.0:
            raise FloatingPointError("the filter's posterior vanished")
        self.b /= total
        self.off /= total
        self._read()
        self._learn_scale(float(z[self._mode]))
        return self._mode, self._conf

    # --- steps ----------------------------------------------------------------------------------------------
    def _novelty(self, still: float | None) -> float:
        """How new a frame's view is, in [0, 1]: 1 for a moving camera (cue below ``still``, or no cue); for
        one the cue reads as standing, 1 - cue (0: its view again). The frame moves the state that share of
        a step and counts that share of its evidence. Where the map's drive stood too (``route``) the frame
        is read as motion, as the map's references were."""
        if still is None or not stands(still, self.config.still):
            return 1.0
        nxt = self._mode + 1
        if self.route is not None and nxt < self.n_refs and self.route[nxt]:
            return 1.0
        return float(min(max(1.0 - still, 0.0), 1.0))

    def _evidence(self, s: np.ndarray, new: float = 1.0) -> np.ndarray:
        """The frame's robust z-scores less each place's running mean over the stream's moving frames (the
        hubs). A frame joins the means ``HUB_DELAY`` frames late: as the camera passes a place its view
        stands out for a few frames, and those are no hub (counted at once, they would lower the places just
        passed against those ahead and push the answer ahead)."""
        z = robust_z(s)
        m = self.config.hub_memory
        if not m:
            return z
        out = z - self._hub
        if new < 1.0:   # a camera that may stand: its view again teaches no hub
            return out
        self._delay.append(z.astype(np.float32))
        if len(self._delay) > HUB_DELAY:
            self._seen = self._seen * (1.0 - 1.0 / m) + 1.0
            self._hub += (self._delay.popleft() - self._hub) / min(self._seen, m)
        return out

    def _read(self) -> None:
        """The answer, its confidence and the reason for doubt, from the posterior."""
        m = self.b.sum(axis=0)
        self._marginal = m
        mode = int(np.argmax(m))
        near = self.graph.near(mode, self.config.tolerance)
        conf = float(sum(m[lo:hi].sum() for lo, hi in near))
        self._mode, self._conf = mode, min(conf, 1.0)
        rest = max(1.0 - conf, 0.0)
        if self.off >= 0.5 * rest:
            self._why = OFF_MAP
        else:
            far = self.graph.near(mode, max(self.config.rival_window, 2 * self.config.tolerance + 1))
            outside = m.copy()
            outside[places(far)] = 0.0
            window = 2 * self.config.tolerance + 1
            rival = float(np.convolve(outside, np.ones(window), "same").max()) if len(outside) else 0.0
            self._why = AMBIGUOUS if rival >= 0.5 * rest else SETTLING

    def _learn_scale(self, z_answer: float) -> None:
        """Add the answered place's z-score to the scale's mean, weighted by the answer's confidence."""
        keep = 1.0 - 1.0 / self.config.scale_memory
        w = self._conf
        self._scale = [self._scale[0] * keep + w * z_answer, self._scale[1] * keep + w]


def bayes_filter(n_refs: int, *, route: np.ndarray | None = None, graph: RouteGraph | None = None,
                 reach: int = 0, **params) -> BayesFilter:
    """The registry's ``stream-filter`` (``params.STREAM_FILTER``); ``route``, ``graph`` and ``reach`` are the map's
    (``Matcher.on_route``): a rival lies beyond ``reach`` as well as beyond ``rival_window``."""
    config = FilterConfig.of(params)
    if reach > config.rival_window:
        config = replace(config, rival_window=reach)
    return BayesFilter(n_refs, config, graph, route)


bayes_filter.searches_locally = BayesFilter.searches_locally   # type: ignore[attr-defined]
