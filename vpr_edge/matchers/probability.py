"""The stream matcher with a line from a model of "not this place": its score is the probability that its
answer is right (``verdict``), estimated from the map and the stream alone, so that one line, the target
precision, is meant to mean the same on every front end. The trajectories, the motion cue, the drives and the
searches are the ``stream`` matcher's (``road.RoadMatcher``); only the verdict differs.

    probability = trajectory * view

``trajectory``: how far the best trajectory stands out of the rival trajectories' null, in that null's own
tail scale (``verdict.trajectory_probability``); ``view``: whether the frames still show the answer's place
(``verdict.ViewFilter``). A frame is lost below the line; ``why()`` names the weaker factor.

With ``decoy`` (the registry's ``stream-decoy``; ``road.RoadMatcher``'s decoy) the probability is 0 while the
stream's best trajectories do not stand above those over the map reversed (imagery of a place the map does
not hold).
"""
from __future__ import annotations

import numpy as np

from vpr_edge.matchers.base import AMBIGUOUS, NO_TRAJECTORY, WEAK_VIEW
from vpr_edge.matchers.road import RoadMatcher
from vpr_edge.matchers.route import Intervals, max_outside
from vpr_edge.matchers.constants import DOUBT_SHARE, FIRM, FIRM_RIVAL, VIEW_LEARN
from vpr_edge.matchers.verdict import (RecentViews, TailScale, ViewFilter, block_peaks,
                                       local_best, rival_weight, spacings, trajectory_probability, view_quantile)

# the lock's rules of the ``stream`` matcher, which this one's verdict replaces (``params.LOCK_RULES``)
_UNUSED = {"lock": 0.0, "evidence": 0.0, "evidence_decay": 0.0, "unique": 0.0, "hold": 1.0}


class ProbabilityMatcher(RoadMatcher):
    """``road.RoadMatcher`` whose score is the probability that its answer is right (see the module
    docstring). Parameters: ``matchers.params.STREAM`` less the lock's rules (``params.LOCK_RULES``)."""

    def __init__(self, n_refs: int, **params) -> None:
        super().__init__(n_refs, **_UNUSED, **params)
        self._tail = TailScale()      # the null's tail scale
        self._view = ViewFilter()     # whether the frames still show the answer's place
        self._recent = RecentViews(n_refs)   # each place's recent views: this stream's hubs
        self._far = (np.zeros(0), np.zeros(0, np.int64))   # rival peaks and their blocks, last whole-route frame

    def reset(self) -> None:
        super().reset()
        self._tail, self._view, self._recent = TailScale(), ViewFilter(), RecentViews(self.n_refs)
        self._far = (np.zeros(0), np.zeros(0, np.int64))

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
            max_outside(values, where, self.graph.near(ref, self.window)) < FIRM_RIVAL * best
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
        return trajectory_probability(weight), top >= DOUBT_SHARE * weight
