"""The stream matcher with a line from a model of "not this place": its score is the probability that its
answer is right (``verdict``), estimated from the map and the stream alone, so that one line, the target
precision, is meant to mean the same on every front end. The trajectories, the motion cue, the drives and the
searches are the ``stream`` matcher's (``road.RoadMatcher``); only the verdict differs.

    probability = trajectory * view

``trajectory``: how far the best trajectory stands out of the rival trajectories' null, in that null's own
tail scale (``verdict.trajectory_probability``); ``view``: whether the frames still show the answer's place
(``verdict.ViewFilter``). A frame is lost below the line; ``why()`` names the weaker factor.

With ``decoy`` (the registry's ``stream-decoy``) the same trajectories also run over the map's references in
reverse order, and the probability is 0 while the stream's best trajectories do not stand above their decoy's
(``verdict.DecoyGate``: imagery of a place the map does not hold). The decoy reads every reference every
frame (no local search, no index: ``wanted`` is always None), so it costs a second pass of the recursion.
"""
from __future__ import annotations

import numpy as np

from vpr_edge.matchers.base import AMBIGUOUS, NO_TRAJECTORY, WEAK_VIEW
from vpr_edge.matchers.road import RoadMatcher
from vpr_edge.matchers.route import Intervals, max_outside
from vpr_edge.matchers.verdict import (FIRM, VIEW_LEARN, DecoyGate, RecentViews, TailScale, ViewFilter,
                                       block_peaks, local_best, rival_weight, spacings, trajectory_probability,
                                       view_quantile)

# the lock's rules of the ``stream`` matcher, which this one's verdict replaces (``params.LOCK_RULES``)
_UNUSED = {"lock": 0.0, "evidence": 0.0, "evidence_decay": 0.0, "unique": 0.0, "hold": 1.0}


def reversed_stands(route: np.ndarray) -> np.ndarray:
    """Where the map's drive stood (R,) bool, True where a reference shows the view of the one before it ->
    the same for the references in reverse order (there, the one before a reference is the one after it)."""
    route = np.asarray(route, bool)
    return np.r_[False, route[::-1][:-1]]


class ProbabilityMatcher(RoadMatcher):
    """``road.RoadMatcher`` whose score is the probability that its answer is right (see the module
    docstring). Parameters: ``matchers.params.STREAM`` less the lock's rules (``params.LOCK_RULES``)."""

    def __init__(self, n_refs: int, *, decoy: bool = False, route: np.ndarray | None = None, graph=None,
                 reach: int = 0, **params) -> None:
        super().__init__(n_refs, **_UNUSED, route=route, graph=graph, reach=reach, **params)
        self._tail = TailScale()      # the null's tail scale
        self._view = ViewFilter()     # whether the frames still show the answer's place
        self._recent = RecentViews(n_refs)   # each place's recent views: this stream's hubs
        self._far = (np.zeros(0), np.zeros(0, np.int64))   # rival peaks and their blocks, last whole-route frame
        # the decoy: the same recursion over the references in reverse order, whole route every frame
        self._decoy = None if not decoy else RoadMatcher(
            n_refs, **_UNUSED, **(params | {"window": 0}), route=None if route is None else reversed_stands(route),
            reach=reach)
        self._gate = DecoyGate() if decoy else None
        if decoy:
            self.around = None   # type: ignore[assignment]   # whole rows: no search around an index's candidates

    def wanted(self) -> np.ndarray | None:
        return None if self._decoy is not None else super().wanted()

    def update(self, sim_row: np.ndarray, refs: np.ndarray | None = None,
               still: float | None = None) -> tuple[int, float]:
        if self._decoy is not None:
            if refs is not None:
                raise ValueError("stream-decoy reads every reference: give the whole row")
            self._decoy.update(np.asarray(sim_row)[::-1], None, still)
        return super().update(sim_row, refs, still)

    def reset(self) -> None:
        super().reset()
        self._tail, self._view, self._recent = TailScale(), ViewFilter(), RecentViews(self.n_refs)
        self._far = (np.zeros(0), np.zeros(0, np.int64))
        if self._decoy is not None:
            self._decoy.reset()
            self._gate = DecoyGate()

    def _verdict(self, ref: int, best: float, values: np.ndarray, where: np.ndarray | None, part: np.ndarray,
                 probe: np.ndarray, mean: float, std: float, standing: bool) -> tuple[float, bool]:
        near = self.graph.near(ref, self.rival_window)
        trajectory, doubt = self._trajectory(ref, best, values, where, near, standing)
        if not standing:   # a standing frame's view again says nothing new
            at = slice(None) if where is None else where
            z = (part - mean) / std
            views = self._recent.corrected(z, at)   # the frame's views less this stream's hubs
            self._recent.add(z, at)
            here = self._answer_view(ref, where, views)
            null = local_best(views, where, near)
            self._view.update(view_quantile(null, float(here.max())), trajectory >= VIEW_LEARN)
        view = self._view.p
        self._why = WEAK_VIEW if view <= trajectory else AMBIGUOUS if doubt else NO_TRAJECTORY
        held = bool(self.window) and trajectory >= FIRM and \
            max_outside(values, where, self.graph.near(ref, self.window)) < 0.5 * best
        if self._gate is not None and not self._gate.update(best, self._decoy.best()):
            self._why = NO_TRAJECTORY   # no trajectory stands above the reversed map's
            return 0.0, held
        return trajectory * view, held

    def _trajectory(self, ref: int, best: float, values: np.ndarray, where: np.ndarray | None, near: Intervals,
                    standing: bool) -> tuple[float, bool]:
        """-> (the probability that the best trajectory, ``best`` at ``ref``, is the place rather than a rival,
        whether one rival holds most of the doubt). ``values``: the best trajectory ending at each place of
        ``where`` (None: every place); the rivals are the block peaks beyond ``near`` on the answer's own drive
        (another drive may be the same road driven again), with the peaks of blocks this frame did not search
        as the last whole-route frame left them; every drive's teach the null's scale."""
        width = self.rival_window or 1
        peaks, blocks = block_peaks(values, where, width, near)
        if where is None:
            self._far = (peaks, blocks)
            far_peaks, far_blocks = np.zeros(0), np.zeros(0, np.int64)
        else:   # blocks outside the windows searched: as last seen
            kept_peaks, kept_blocks = self._far
            out = ~np.isin(kept_blocks, np.unique(where // width))
            far_peaks, far_blocks = kept_peaks[out], kept_blocks[out]
        if len(far_peaks):
            blocks, peaks = np.concatenate([blocks, far_blocks]), np.concatenate([peaks, far_peaks])
        if not standing:
            self._tail.add(spacings(peaks))
        first, last = self.graph.bounds(ref)
        rivals = peaks[(blocks >= first // width) & (blocks <= last // width)]
        beta = self._tail.value
        weight = rival_weight(best, rivals, beta)
        if not len(rivals) or beta is None:
            return trajectory_probability(weight), False
        top = float(np.exp(min((float(rivals.max()) - best) / beta, 50.0)))
        return trajectory_probability(weight), top >= 0.5 * weight
