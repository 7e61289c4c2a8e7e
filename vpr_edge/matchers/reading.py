"""What the stream matcher's verdict reads of a frame, and the verdict's contract: the trajectory recursion
(``road.RoadMatcher``) finds the answer; a *verdict* says how sure it is and why a frame is lost. Two
verdicts exist, each testable alone over a ``FrameReading``: the lock's rules (``lock.LockVerdict``, the
``stream`` matcher's) and a model of "not this place" (``probability.ProbabilityVerdict``, ``stream-prob``'s).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from vpr_edge.matchers.base import NO_TRAJECTORY
from vpr_edge.matchers.route import RouteGraph


@dataclass(frozen=True)
class FrameReading:
    """One frame as the trajectories left it. ``ref``: the answer (the best trajectory's place); ``best``: that
    trajectory's score H; ``values`` (n,): the best trajectory ending at each place of ``where`` (sorted place
    numbers, (n,); None: every place, in order); ``part`` (n,): the frame's similarities to those places;
    ``probe``: its similarities that estimate its ``mean`` and spread ``std`` (the probe sample while searching
    locally, else every reference); ``standing``: the frame shows a standing camera (its view again);
    ``stopped``: no motion cue is given and the best trajectory has speed 0 (the vehicle stands as the
    trajectories read it); ``cued``: a motion cue is given (so a frame not ``standing`` shows a moving
    camera)."""

    ref: int
    best: float
    values: np.ndarray
    where: np.ndarray | None
    part: np.ndarray
    probe: np.ndarray
    mean: float
    std: float
    standing: bool
    stopped: bool = False
    cued: bool = False

    @property
    def places(self) -> np.ndarray | slice:
        """The places ``part`` covers, as an index: ``where``, or every place."""
        return slice(None) if self.where is None else self.where

    @property
    def z(self) -> np.ndarray:
        """``part`` in standard deviations above the frame's mean, (n,)."""
        return (np.asarray(self.part, np.float64) - self.mean) / self.std


@dataclass(frozen=True)
class Judgement:
    """A verdict on one frame: its ``score`` (the matcher's; a lost line is drawn on it), whether the answer is
    ``strong`` enough for a local search to follow it (the matcher adds that no trajectory beyond its window is
    near as strong), ``why`` (``base.LOST_WHY`` or "locked": the first reason the frame is not answered) and,
    for a verdict that models it, the ``probability`` that the answer is right."""

    score: float
    strong: bool
    why: str
    probability: float | None = None   # the probability that the answer is right, where the verdict has one


class Verdict(Protocol):
    """Judges each frame of one stream (it may keep state over the stream; ``reset`` forgets it)."""

    def judge(self, frame: FrameReading) -> Judgement: ...

    def reset(self) -> None: ...


# a verdict for a map: made from the map's route graph and the rival window (places either side of an answer
# that a rival trajectory must lie beyond)
VerdictFactory = Callable[[RouteGraph, int], Verdict]


class TrajectoryOnly:
    """No verdict: score 0, never strong (a matcher whose trajectories alone are read: the decoy)."""

    def __init__(self, graph: RouteGraph, rival_window: int) -> None:
        pass

    def judge(self, frame: FrameReading) -> Judgement:
        return Judgement(0.0, False, NO_TRAJECTORY)

    def reset(self) -> None:
        pass


def answer_view(graph: RouteGraph, ref: int, where: np.ndarray | None, part: np.ndarray) -> np.ndarray:
    """The frame's similarities (``part``, over the places ``where``; None: all) to the answer ``ref`` and its
    neighbours along its drive (one either side where there is one), (1..3,)."""
    first, last = graph.bounds(ref)
    at = int(np.searchsorted(where, ref)) if where is not None else ref
    lo = max(0, at - (1 if ref > first else 0))
    return part[lo:at + (2 if ref < last else 1)]
