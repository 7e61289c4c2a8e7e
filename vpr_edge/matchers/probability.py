"""The stream matcher with a line from a model of "not this place": its score is the probability that its
answer is right (``verdict``), estimated from the map and the stream alone, so that one line, the target
precision, is meant to mean the same on every front end. The trajectories, the motion cue, the drives and the
searches are the ``stream`` matcher's (``road.RoadMatcher``); only the verdict differs (``ProbabilityVerdict``
in place of ``lock.LockVerdict``).

    probability = place * view

``place``: how far the best trajectory stands out of the rival trajectories' null, in that null's own tail
scale, and out of the trajectories ending at the places next to the answer: the probability that the place
lies within ``ANSWER_SLACK`` of the answer (``verdict.place_probability``); ``view``: whether the frames still
show the answer's place (``verdict.ViewFilter``). The score, on which the line is drawn, is the precision
expected of the stream's recent answers at least as sure (``verdict.line_score``; ``probability()`` gives the
probability itself). A frame is lost below the line; ``why()`` names the weaker factor.

With ``decoy`` (the registry's ``stream-decoy``; ``road.RoadMatcher``'s decoy) the probability is 0 while the
stream's best trajectories do not stand above those over the map reversed (imagery of a place the map does
not hold).
"""
from __future__ import annotations

from collections import deque

import numpy as np

from vpr_edge.matchers.base import AMBIGUOUS, NO_TRAJECTORY, WEAK_VIEW
from vpr_edge.matchers.constants import ANSWER_SLACK, DOUBT_SHARE, FIRM, LINE_MEMORY, PLACE_SCALE, VIEW_LEARN
from vpr_edge.matchers.reading import FrameReading, Judgement, answer_view
from vpr_edge.matchers.road import RoadMatcher
from vpr_edge.matchers.route import Intervals, RouteGraph
from vpr_edge.matchers.verdict import (RecentViews, TailScale, ViewFilter, block_peaks, line_score,
                                       local_best, near_values, place_probability, rival_weight, spacings,
                                       trajectory_probability, view_quantile)

# the lock's rules of the ``stream`` matcher, which this one's verdict replaces (``params.LOCK_RULES``)
_UNUSED = {"lock": 0.0, "evidence": 0.0, "evidence_decay": 0.0, "hub": 0.0, "unique": 0.0, "confirm": 1, "stuck": 0,
           "trust": 1.0, "hold": 1.0}


def probability_matcher(n_refs: int, **params) -> RoadMatcher:
    """``road.RoadMatcher`` whose score is the probability that its answer is right (``ProbabilityVerdict``).
    Parameters: ``matchers.params.STREAM`` less the lock's rules (``params.LOCK_RULES``)."""
    return RoadMatcher(n_refs, **_UNUSED, **params, verdict=ProbabilityVerdict)


probability_matcher.searches_locally = RoadMatcher.searches_locally   # type: ignore[attr-defined]   # it makes those


class ProbabilityVerdict:
    """The probability that the answer is right, ``place * view`` (the module docstring), over one stream
    on the map whose route graph is ``graph``; rivals lie beyond ``rival_window`` places of the answer. Strong
    enough for a local search at a trajectory probability of ``FIRM``; ``why`` names the weaker factor."""

    def __init__(self, graph: RouteGraph, rival_window: int) -> None:
        self.graph, self.rival_window = graph, rival_window
        self.reset()

    def reset(self) -> None:
        self._tail = TailScale()      # the null's tail scale
        self._view = ViewFilter()     # whether the frames still show the answer's place
        self._recent = RecentViews(self.graph.n_refs)   # each place's recent views: this stream's hubs
        self._far = (np.zeros(0), np.zeros(0, np.int64))   # rival peaks and their blocks, last whole-route frame
        self._sure: deque[float] = deque(maxlen=LINE_MEMORY)   # the last frames' probabilities (the line's)

    def judge(self, f: FrameReading) -> Judgement:
        near = self.graph.near(f.ref, self.rival_window)
        rivals, beta, doubt = self._rivals(f.ref, f.best, f.values, f.where, near, f.standing)
        trajectory = trajectory_probability(rivals)   # the answer's trajectory rather than a rival's
        places, values = near_values(f.values, f.where, near)
        place = place_probability(f.best, places, values, self.graph.near(f.ref, ANSWER_SLACK), rivals,
                                  None if beta is None else PLACE_SCALE * beta)
        if not f.standing:   # a standing frame's view again says nothing new
            views = self._recent.read(f.z, f.places, learn=True)   # the frame's views less this stream's hubs
            here = answer_view(self.graph, f.ref, f.where, views)
            null = local_best(views, f.where, near)
            self._view.update(view_quantile(null, float(here.max())), trajectory >= VIEW_LEARN)
        view = self._view.p
        why = WEAK_VIEW if view <= place else AMBIGUOUS if doubt else NO_TRAJECTORY
        probability = place * view
        self._sure.append(probability)
        return Judgement(line_score(probability, np.fromiter(self._sure, float, len(self._sure))),
                         trajectory >= FIRM, why, probability)

    def _rivals(self, ref: int, best: float, values: np.ndarray, where: np.ndarray | None, near: Intervals,
                standing: bool) -> tuple[float, float | None, bool]:
        """-> (how much the rival trajectories explain the best one, ``best`` at ``ref`` (``rival_weight``),
        the null's tail scale (None: not known yet), whether one rival holds most of the doubt). ``values``: the
        best trajectory ending at each place of ``where`` (None: every place); the rivals are the block peaks
        beyond ``near`` on the answer's own drive (another drive may be the same road driven again), with the
        peaks of blocks this frame did not search as the last whole-route frame left them; every drive's teach
        the null's scale."""
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
            return weight, beta, False
        top = float(np.exp(min((float(rivals.max()) - best) / beta, 50.0)))
        return weight, beta, top >= DOUBT_SHARE * weight
