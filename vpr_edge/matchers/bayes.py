"""The ``stream`` matcher: a Bayes filter over (place along the route, speed), plus one off-map state.

The hidden state of a frame is where the camera is on the map and how fast it moves along it, in places a
frame (standing, half a place, or 1 to ``vmax`` in steps of ``speed_step``: ``filter_motion``), or that it is
somewhere the map does not hold (*off-map*). Each frame:

1. **Predict** (the motion model). A speed changes to the next one up or down with probability
   ``speed_change`` each (``filter_motion.speed_kernel``; on a frame with no motion cue a stopped camera also
   starts again, ``filter_motion.blind``); then the camera moves on by its speed, a fractional speed by whole
   places in a fixed cycle (1.5: one, then two; ``filter_motion.phases``). Mass that runs past a drive's last
   place goes on into the drives its junctions say follow it (``route.RouteGraph``; ``filter_motion.overruns``),
   else leaves the map; a junction from inside a drive (a fork) passes a share ``JOIN`` of its places' mass on
   to the other drive. Every frame, ``leave`` of the on-map
   mass moves off the map, ``jump`` of it to a place anywhere on the map (a re-localisation), and ``enter`` of
   the off-map mass comes back onto the map at any place. Mass coming onto the map (the prior too) takes the
   speeds' long run under the motion model (``filter_motion.stationary``): the slow speed is rare there.
2. **Correct** (the likelihood of the frame's similarity row). The row is read on its own scale: robust
   z-scores ``z = (s - median) / spread`` (``robust_z``: the bulk's or the upper tail's spread, the larger;
   a front end whose unrelated places often stand out reads lower), less each place's running
   mean over this stream's moving frames (``hub_memory``: a place that looks like every frame is no
   evidence; a frame joins those means ``HUB_DELAY`` frames late), each counted up to the likelihood's
   scale (below) plus ``Z_CAP``: a spike beyond what the true place gives, at a place that looks like
   anything, is no more evidence. The likelihood ratio of "the camera is at place p" against "off the map" is

       LR(p) = exp(beta * z_p - beta^2 / 2)

   with the row's bulk a standard normal null (most of a row is "not this place") and the true place's
   z-score normal about ``beta``; the off-map state's likelihood is 1. A row says "on the map" where a
   place stands out of it, and "here" where that place lies where the motion model predicted it. ``beta``
   is the stream's own: the running mean of the z-score at the answered place, weighted by the answer's
   confidence (a prior of ``SCALE_PRIOR`` for ``SCALE_PRIOR_FRAMES`` frames), times ``temper`` (< 1:
   neighbouring frames and places see alike, so a frame is worth less than an independent observation).
   A front end whose cosines lie in 0.9-1.0 and one whose cosines spread over 0-1 are read alike.
3. The **motion cue** (``motion.MotionCue``) observes the speed: speed 0 and the moving speeds are weighed
   by how likely the frame's cue is for a standing camera (about 0.75) and a moving one (about 0)
   (``filter_motion.cue_weights``). A frame whose cue reaches ``still`` (its view is nearly the last
   moving frame's) counts of its view's evidence only the probability, by the same two normals at even
   odds, that the camera moves all the same (a view seen again says nothing new), and as much
   of the frame's ``leave``, ``jump`` and ``enter`` (a camera that stands stays where it is: a long stop
   keeps its answer). Where the map's own drive stood (``route``) the frame is read as motion. A frame whose
   cue reaches ``REPEAT`` is the last frame again, bit for bit (a duplicated frame: a video's frame rate
   raised by repeating frames): it is no new observation, and the filter skips it, answering as before.

The answer is the place of the posterior's mode (summed over speeds), its **confidence** the posterior mass
within ``tolerance`` places of it along the route: the probability that the answer is within ``tolerance``
of the true place. A frame is lost below the line (``--target-precision``); ``why`` says what holds the
missing mass: ``off-map`` (the off-map state), ``ambiguous`` (another stretch of the route) or ``settling``
(spread thinly: not converged yet).

On a route of more than ``4 * window`` places a firm answer (confidence at least ``hold``), or a frame read as
standing after a window, lets the next frame read only the places within ``window`` of it
(``filter_motion.Window``: the rest of the on-map mass held as one number, *elsewhere*, its likelihood that of
the off-map state), its row's median and spread read on a fixed ``probe`` sample; ``span`` frames in every
``check`` read the whole route, as ``stream-rules``' local search does. On such a route with an index, a frame
that would read the whole route reads instead the places within ``seek`` of the index's candidates and within
``max(seek, window / 4)`` of the ``peaks`` most probable places held (``around``): the state never spans the
whole route.

State: (V, R) float64 over V rows, one per frame of each speed's cycle (13 at the defaults; the columns held
while local), the hub means and ``HUB_DELAY`` z-score rows, whatever the stream's length; a frame costs
O(V² R), O(V² W) over W places held.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import replace
from statistics import NormalDist

import numpy as np

from vpr_edge.matchers.base import AMBIGUOUS, OFF_MAP, SETTLING
from vpr_edge.matchers.constants import (HUB_DELAY, MIN_SPREAD, REPEAT, SCALE_BOUNDS, SCALE_PRIOR, SCALE_PRIOR_FRAMES,
                                         START_OFF, TAIL_QUANTILE, Z_CAP)
from vpr_edge.matchers.filter_config import FilterConfig
from vpr_edge.matchers.filter_motion import Transitions, Window, cue_weights, regather
from vpr_edge.matchers.motion import stands
from vpr_edge.matchers.route import RouteGraph, places
from vpr_edge.matchers.search_policy import around_candidates, best_hypotheses, local_next

_Z75 = NormalDist().inv_cdf(0.75)                     # a standard normal's 75th percentile (0.674)
_Z_TAIL = NormalDist().inv_cdf(TAIL_QUANTILE / 100.0)  # ... and its TAIL_QUANTILE-th



def quantiles(values: np.ndarray, percents: tuple[float, ...]) -> np.ndarray:
    """The ``percents`` (0-100) of ``values`` (n,), n >= 1, as ``np.percentile`` gives them (linear), from
    one partial sort: a frame's row is read this way every frame."""
    a = np.asarray(values, np.float64).reshape(-1)
    q = np.asarray(percents, np.float64) / 100.0 * (len(a) - 1)
    lo = np.floor(q).astype(np.int64)
    hi = np.minimum(lo + 1, len(a) - 1)
    part = np.partition(a, np.unique(np.concatenate([lo, hi])))
    return part[lo] + (part[hi] - part[lo]) * (q - lo)


def robust_z(row: np.ndarray, sample: np.ndarray | None = None) -> np.ndarray:
    """A similarity row (n,) -> its robust z-scores: less the median, over the spread, all read on ``sample``
    (values; None: the row). The spread is the larger of the bulk's (inter-quartile range / 1.349) and the
    upper tail's (the 75th to the ``TAIL_QUANTILE``-th percentile over the same span of a standard normal):
    on a front end whose unrelated places often stand out (aliasing), a high similarity is worth less."""
    ref = row if sample is None else sample
    q25, q50, q75, qt = quantiles(ref, (25.0, 50.0, 75.0, TAIL_QUANTILE))
    bulk = (q75 - q25) / (2.0 * _Z75)
    tail = (qt - q75) / (_Z_TAIL - _Z75)
    return (row - q50) / max(bulk, tail, MIN_SPREAD)


def likelihood(z: np.ndarray, beta: float) -> tuple[np.ndarray, float]:
    """Likelihood ratios of "the camera is at place p" against "off the map", up to one factor: (lr (n,), the
    off-map state's likelihood on the same scale). With the row's bulk a standard normal null and the true
    place's z-score normal about ``beta``, the ratio is exp(beta * z - beta^2 / 2); scaled so that the
    largest of the lot is 1 (no overflow)."""
    ll = beta * z - 0.5 * beta * beta
    top = max(float(ll.max()), 0.0)
    return np.exp(ll - top), math.exp(-top)


class BayesFilter:
    """The online ``stream`` matcher (module docstring) over ``n_refs`` places of ``graph``'s route."""

    searches_locally = True

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
        self.local = bool(config.window) and n_refs > 4 * config.window
        rng = np.random.default_rng(0)
        self._probe = np.sort(rng.choice(n_refs, min(n_refs, config.probe), replace=False)) if self.local else None
        self.reset()

    def reset(self) -> None:
        """Forget the stream: the prior (``START_OFF`` off the map, the rest anywhere on it; on a long route
        held as *elsewhere*, no place yet)."""
        self.off = START_OFF
        self.cols: np.ndarray | None = None   # the places held while local (None: every place)
        self.elsewhere = 0.0                  # on-map mass outside the places held
        self._window: Window | None = None
        self._whole = True                    # the next frame reads the whole route (or around candidates)
        if self.local:
            self.b, self.cols = np.zeros((self.moves.n_speeds, 0)), np.zeros(0, np.int64)
            self.elsewhere = 1.0 - START_OFF
        else:
            self.b = self.moves.entry() * (1.0 - START_OFF)
        self._held = 0                        # frames in a row with a firm answer
        self._hub = np.zeros(self.n_refs)
        self._seen = 0.0                      # moving frames in the hub means (an exponential count)
        self._delay: deque[tuple[np.ndarray | None, np.ndarray]] = deque()   # last HUB_DELAY frames' z-scores
        self._scale = [0.0, 0.0]              # confidence-weighted sum of the answer's z, and of the weights
        self._mode, self._conf, self._why = 0, 0.0, SETTLING
        self._rank = self.b.sum(axis=0) if self.cols is None else np.zeros(self.n_refs)
        self._ranked: np.ndarray | None = None   # the places of ``_rank`` set last while local

    # --- the contract (``base.OnlineMatcher``) --------------------------------------------------------------
    def wanted(self) -> np.ndarray | None:
        """The places the next ``update`` reads, then the probe (None: every place, or ``around`` an index's
        candidates)."""
        if self.cols is None or self._whole:
            return None
        return np.concatenate([self.cols, self._probe])

    def around(self, candidates: np.ndarray) -> np.ndarray | None:
        """What the next ``update`` reads when ``wanted()`` asked for the whole route and an index answered
        with ``candidates`` (places): on a long route the places within ``seek`` of each candidate and within
        ``max(seek, window / 4)`` of the ``peaks`` most probable places held, then the probe; the mass moves
        there (the rest is *elsewhere*). On a short route: None, every place."""
        if not self.local:
            return None
        c = self.config
        reach = max(c.seek, c.window // 4)
        held = best_hypotheses(self.b.sum(axis=0), self.cols, c.peaks, reach) if self.b.size else []
        target = places(around_candidates(self.graph, candidates, c.seek, held, reach, 1))
        if not len(target):
            return None
        self._move(target)
        return np.concatenate([self.cols, self._probe])

    def position(self) -> None:
        return None

    def probability(self) -> float:
        """The probability that the last answer lies within ``tolerance`` of the true place."""
        return self._conf

    def why(self) -> str:
        """What holds the probability the last answer is not right (``base.FILTER_REASONS``)."""
        return self._why

    def ranking(self) -> np.ndarray:
        """The posterior probability of each place (R,), summed over speeds (0 outside a window)."""
        return self._rank

    @property
    def off_map(self) -> float:
        """The posterior probability that the camera is off the map."""
        return self.off

    @property
    def scale(self) -> float:
        """How far the true place's z-score stands out now: the answers' confidence-weighted mean, with its
        prior, kept in ``SCALE_BOUNDS`` (module docstring)."""
        s, w = self._scale
        mean = (s + SCALE_PRIOR * SCALE_PRIOR_FRAMES) / (w + SCALE_PRIOR_FRAMES)
        return float(np.clip(mean, *SCALE_BOUNDS))

    @property
    def beta(self) -> float:
        """The likelihood's scale now: ``temper`` times ``scale`` (module docstring)."""
        return self.config.temper * self.scale

    def update(self, sim_row: np.ndarray, refs: np.ndarray | None = None,
               still: float | None = None) -> tuple[int, float]:
        """The frame's similarities -> (answer, confidence): to every place (R,), or with ``refs`` exactly to
        the places ``wanted()`` named; ``still``: the frame's motion cue."""
        s = np.asarray(sim_row, np.float64)
        if still is not None and self.config.still and still >= REPEAT:   # a duplicated frame: nothing new
            return self._mode, self._conf
        part, sample = self._split(s, refs)
        new, route_stands = self._novelty(still)
        z = np.minimum(self._evidence(part, sample, new), self.scale + Z_CAP)   # (step 2)
        cued = still is not None and bool(self.config.still)
        self._predict(cued, new)
        if cued:   # the cue observes the speed: 0 where the view is the same
            moving, standing = cue_weights(float(still), route_stands)
            self.b[0] *= standing
            self.b[1:] *= moving
            share = moving * (1.0 - 1.0 / self.moves.n_speeds) + standing / self.moves.n_speeds
            self.off *= share
            self.elsewhere *= share
        lr, off_lr = likelihood(z, new * self.beta)
        self.b *= lr[None, :]
        self.off *= off_lr
        self.elsewhere *= off_lr   # places not read: on average as likely as off the map (E[lr] = 1)
        total = float(self.b.sum()) + self.off + self.elsewhere
        if not math.isfinite(total) or total <= 0.0:
            raise FloatingPointError("the filter's posterior vanished")
        self.b /= total
        self.off /= total
        self.elsewhere /= total
        at = self._read()
        self._learn_scale(float(z[at]))
        self._follow(new < 1.0)
        return self._mode, self._conf

    # --- steps ----------------------------------------------------------------------------------------------
    def _split(self, s: np.ndarray, refs: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
        """A frame's similarities -> (those of the places held, the sample its median and spread are read
        on; None: the row itself). A whole row where the whole route was wanted brings the mass onto every
        place first."""
        if self._whole and refs is None and self.cols is not None:
            self._move(None)
        if self.cols is None:
            if refs is not None or s.shape != (self.n_refs,):
                raise ValueError(f"similarity row must have shape ({self.n_refs},), got {s.shape}")
            return s, None
        n = len(self.cols)
        if refs is not None:
            if len(refs) != n + len(self._probe) or len(s) != len(refs):
                raise ValueError("similarities must cover the references wanted() named")
            return s[:n], s[n:]
        if s.shape != (self.n_refs,):
            raise ValueError(f"similarity row must have shape ({self.n_refs},), got {s.shape}")
        return s[self.cols], s[self._probe]

    def _predict(self, cued: bool, hazard: float = 1.0) -> None:
        """The motion model, on the whole route or the window; a frame with no motion cue (``cued`` False)
        moves its speeds by the blind kernel (``filter_motion.blind``); ``hazard`` of ``leave``, ``jump`` and
        ``enter`` happen (the frame's novelty: a camera that stands neither leaves the map nor comes back)."""
        kernel = self.moves.kernel if cued else self.moves.blind_kernel
        if self.cols is None:
            self.b, self.off = self.moves.predict(self.b, self.off, kernel, hazard)
            return
        c = self.config
        self.b, self.off, self.elsewhere = self._window.predict(self.b, self.off, self.elsewhere, hazard * c.leave,
                                                                hazard * c.jump, hazard * c.enter, kernel)

    def _novelty(self, still: float | None) -> tuple[float, bool]:
        """(How new a frame's view is, in [0, 1]; whether the map's drive stood here too). Novelty is 1 for a
        moving camera (cue below ``still``, or no cue); for one the cue reads as standing, the probability
        that the camera moves all the same, from the cue's two normals at even odds (``cue_weights``; 0: its
        view again). The frame counts that share of its evidence. Where the map's drive stood too (``route``)
        the frame is read as motion, as the map's references were: novelty 1, and ``cue_weights`` weighs it
        as moving."""
        if still is None or not stands(still, self.config.still):
            return 1.0, False
        nxt = self._mode + 1
        if self.route is not None and nxt < self.n_refs and self.route[nxt]:
            return 1.0, True
        moving, standing = cue_weights(float(still))
        return moving / (moving + standing), False

    def _evidence(self, s: np.ndarray, sample: np.ndarray | None = None, new: float = 1.0) -> np.ndarray:
        """The frame's robust z-scores (at the places held; median and spread from ``sample``, None: ``s``)
        less each place's running mean over the stream's moving frames (the hubs). A frame joins the means
        ``HUB_DELAY`` frames late: as the camera passes a place its view stands out for a few frames, and
        those are no hub (counted at once, they would lower the places just passed against those ahead and
        push the answer ahead)."""
        z = robust_z(s, sample)
        m = self.config.hub_memory
        if not m:
            return z
        cols = self.cols
        out = z - (self._hub if cols is None else self._hub[cols])
        if new < 1.0:   # a camera that may stand: its view again teaches no hub
            return out
        self._delay.append((cols, z.astype(np.float32)))
        if len(self._delay) > HUB_DELAY:
            self._seen = self._seen * (1.0 - 1.0 / m) + 1.0
            where, old = self._delay.popleft()
            rate = 1.0 / min(self._seen, m)
            if where is None:
                self._hub += (old - self._hub) * rate
            else:
                self._hub[where] += (old - self._hub[where]) * rate
        return out

    def _mass_near(self, m: np.ndarray, intervals: list[tuple[int, int]]) -> float:
        """The mass of ``m`` (one value per place held) at the places of ``intervals``."""
        if self.cols is None:
            return float(sum(m[lo:hi].sum() for lo, hi in intervals))
        return float(sum(m[np.searchsorted(self.cols, lo):np.searchsorted(self.cols, hi)].sum()
                         for lo, hi in intervals))

    def _read(self) -> int:
        """The answer, its confidence and the reason for doubt, from the posterior; returns the answer's
        column among the places held."""
        m = self.b.sum(axis=0)
        self._set_rank(m)
        at = int(np.argmax(m))
        mode = at if self.cols is None else int(self.cols[at])
        conf = self._mass_near(m, self.graph.near(mode, self.config.tolerance))
        self._mode, self._conf = mode, min(conf, 1.0)
        rest = max(1.0 - conf, 0.0)
        if self.off >= 0.5 * rest:
            self._why = OFF_MAP
        else:
            far = self.graph.near(mode, max(self.config.rival_window, 2 * self.config.tolerance + 1))
            outside = m.copy()
            held = places(far) if self.cols is None else self._window.positions(places(far))
            outside[held if self.cols is None else held[0][held[1]]] = 0.0
            window = 2 * self.config.tolerance + 1
            rival = float(np.convolve(outside, np.ones(window), "same").max()) if len(outside) else 0.0
            self._why = AMBIGUOUS if rival >= 0.5 * rest else SETTLING
        return at

    def _set_rank(self, m: np.ndarray) -> None:
        """``ranking()``'s array from the marginal ``m`` of the places held."""
        if self.cols is None:
            self._rank, self._ranked = m, None
            return
        if self._ranked is None or len(self._rank) != self.n_refs or self._rank is m:
            self._rank = np.zeros(self.n_refs)
        else:
            self._rank[self._ranked] = 0.0
        self._rank[self.cols] = m
        self._ranked = self.cols

    def _follow(self, standing: bool = False) -> None:
        """Choose the places the next frame reads (module docstring): the window around a firm answer, or
        every place; the mass moves with the choice. A frame read as standing (``standing``: its view again,
        little new evidence) keeps a window it read: there is nothing new to look for elsewhere."""
        if not self.local:
            return
        if standing and self.cols is not None:
            self._move(places(self.graph.near(self._mode, self.config.window)))
            return
        self._held = self._held + 1 if self._conf >= self.config.hold else 0
        self._whole = not local_next(self._held, self.config.check, self.config.span)
        if not self._whole:
            self._move(places(self.graph.near(self._mode, self.config.window)))

    def _move(self, new: np.ndarray | None) -> None:
        """Hold the places ``new`` (sorted; None: every place): the mass of places no longer held joins
        *elsewhere*, places newly held take their even share of it (over the speed rows by the long run)."""
        cols = self.cols if self.cols is not None else np.arange(self.n_refs)
        target = new if new is not None else np.arange(self.n_refs)
        self.b, self.elsewhere = regather(self.b, cols, self.elsewhere, target, self.n_refs, self.moves.prior)
        if new is None:
            self.elsewhere = 0.0
        self.cols = new
        self._window = None if new is None else Window(self.graph, new, self.moves.moves, self.moves.prior,
                                                             self.moves.over, self.moves.forks)
        self._whole = self._whole and new is None

    def _learn_scale(self, z_answer: float) -> None:
        """Add the answered place's z-score to the scale's mean, weighted by the answer's confidence."""
        keep = 1.0 - 1.0 / self.config.scale_memory
        w = self._conf
        self._scale = [self._scale[0] * keep + w * z_answer, self._scale[1] * keep + w]


def bayes_filter(n_refs: int, *, route: np.ndarray | None = None, graph: RouteGraph | None = None,
                 reach: int = 0, **params) -> BayesFilter:
    """The registry's ``stream`` (``params.STREAM``); ``route``, ``graph`` and ``reach`` are the map's
    (``Matcher.on_route``): a rival lies beyond ``reach`` as well as beyond ``rival_window``."""
    config = FilterConfig.of(params)
    if reach > config.rival_window:
        config = replace(config, rival_window=reach)
    return BayesFilter(n_refs, config, graph, route)


bayes_filter.searches_locally = BayesFilter.searches_locally   # type: ignore[attr-defined]
