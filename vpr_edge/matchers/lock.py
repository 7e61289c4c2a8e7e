"""The ``stream-rules`` matcher's verdict: the lock's rules (``road``'s module docstring says what each one guards).

    score = [locked] + uniqueness,   uniqueness = 1 - (H_rival + 1) / (H_best + 1)

A frame is locked when its answer stands out of what the frame sees (the evidence average E >= ``evidence``,
or its trajectory is unambiguous enough to outweigh a weak view: uniqueness against the answer's own drive
>= ``trust``)
and of what this stream's recent frames saw there (the same average of the answer's view less its place's
mean over the stream's recent moving frames, ``RecentViews``: >= ``hub``; a place that looks like
every frame, imagery of somewhere else the map's place happens to resemble most, does not), its trajectory
has built up (H_best >= ``lock``) and held its place for ``confirm`` frames (``place_jumped``: a best place
that jumps, back onto the map after a detour or onto a look-alike ahead, is answered from its ``confirm``-th
frame there on), has moved with a moving camera (``place_advanced``: a place the answer keeps while the camera
moves on for ``stuck`` frames, as the motion cue says, is a place every frame resembles, not where the vehicle
is) and no rival along the answer's own drive is nearly as strong (uniqueness against it >= ``unique``); the
first rule that fails names why it is lost (``lock_verdict``). So locked frames rank above lost ones, each by
uniqueness. The answer is strong enough for a local search at H_best >= ``hold`` * ``lock``.

The trajectory recursion (``road.RoadMatcher``) finds the answer and hands each frame to the verdict as a
``FrameReading``; the verdict (``LockVerdict``, its parameters a ``LockRules``) answers a ``Judgement``, so each
is testable alone.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vpr_edge.matchers.base import AMBIGUOUS, LOCKED, NO_TRAJECTORY, WEAK_VIEW
from vpr_edge.matchers.constants import HUB_MEMORY, HUB_PRIOR, OFF
from vpr_edge.matchers.route import RouteGraph, inside, max_outside, merge


@dataclass(frozen=True)
class FrameReading:
    """One frame as the trajectories (``road.RoadMatcher``) left it, what the verdict judges. ``ref``: the
    answer (the best trajectory's place); ``best``: that trajectory's score H; ``values`` (n,): the best
    trajectory ending at each place of ``where`` (sorted place numbers, (n,); None: every place, in order);
    ``part`` (n,): the frame's similarities to those places; ``probe``: its similarities that estimate its
    ``mean`` and spread ``std`` (the probe sample while searching locally, else every reference);
    ``standing``: the frame shows a standing camera (its view again); ``stopped``: no motion cue is given and
    the best trajectory has speed 0 (the vehicle stands as the trajectories read it); ``cued``: a motion cue
    is given (so a frame not ``standing`` shows a moving camera)."""

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
    """The verdict on one frame: its ``score`` (the matcher's; the lost line is drawn on it), whether the
    answer is ``strong`` enough for a local search to follow it (the matcher adds that no trajectory beyond its
    window is near as strong) and ``why`` (``base.LOST_WHY`` or "locked": the first reason the frame is not
    answered)."""

    score: float
    strong: bool
    why: str


def answer_view(graph: RouteGraph, ref: int, where: np.ndarray | None, part: np.ndarray) -> np.ndarray:
    """The frame's similarities (``part``, over the places ``where``; None: all) to the answer ``ref`` and its
    neighbours along its drive (one either side where there is one), (1..3,)."""
    first, last = graph.bounds(ref)
    at = int(np.searchsorted(where, ref)) if where is not None else ref
    lo = max(0, at - (1 if ref > first else 0))
    return part[lo:at + (2 if ref < last else 1)]


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


def evidence_average(previous: float | None, here: float, keep: float, standing: bool) -> float:
    """The answer's standing out of its frames (``evidence``): this frame's ``here`` (its similarity in standard
    deviations above the frame's row) joined to the ``previous`` average (None: none yet) with the past's
    weight ``keep`` (``evidence_decay``); a standing frame may raise the average, not lower it."""
    if previous is None:
        return here
    recent = keep * previous + (1.0 - keep) * here
    return max(previous, recent) if standing else recent


def uniqueness(rival: float, best: float) -> float:
    """How far the best trajectory score ``best`` leads a ``rival``'s: 1 - (rival + 1) / (best + 1)."""
    return 1.0 - (rival + 1.0) / (best + 1.0)


def place_jumped(graph: RouteGraph, previous: int | None, ref: int, w: int) -> bool:
    """Whether this frame's answer ``ref`` jumped from the frame before's, ``previous`` (None: the stream's
    first frame, which starts a place): it lies in ``previous``'s drive beyond ``w`` places of it along the
    route (``RouteGraph.near``). A place of another drive is no jump: it may be the same road driven again (as
    the uniqueness rule reads other drives)."""
    if previous is None:
        return True
    return graph.bounds(ref) == graph.bounds(previous) and not inside(np.array([ref]), graph.near(previous, w))[0]


def place_advanced(graph: RouteGraph, anchor: int | None, ref: int) -> bool:
    """Whether this frame's answer ``ref`` has moved on from ``anchor``, where the answer's place last moved
    to (None: none yet): at least one place ahead of it along its drive, more than one behind it (a new
    trajectory: they only run forward), or on another drive. One place back is no move: a trajectory stuck on
    a place answers it and the place just behind it by turns."""
    if anchor is None or graph.bounds(ref) != graph.bounds(anchor):
        return True
    return not -1 <= ref - anchor < 1


def lock_verdict(evidence: float, best: float, own_uniqueness: float, evidence_line: float, lock: float,
                 unique: float, hub_evidence: float = np.inf, hub_line: float = -np.inf, held: int = 1,
                 confirm: int = 1, kept: int = 0, stuck: int = 0, trust: float = np.inf) -> str:
    """The lock's rules, in order: the first that fails names why the frame is lost (``base.LOST_WHY``):
    "weak-view" (``evidence`` below ``evidence_line`` unless ``own_uniqueness`` reaches ``trust``, or
    ``hub_evidence``, the same less the answer's place's recent mean, below ``hub_line``), "no-trajectory"
    (``best`` below ``lock``, the place ``held`` for fewer than ``confirm`` frames, or ``kept`` while the camera
    moved for ``stuck`` frames or more; 0: off), "ambiguous" (``own_uniqueness``, against the best rival along
    the answer's own drive, below ``unique``); else "locked"."""
    if not ((evidence >= evidence_line or own_uniqueness >= trust) and hub_evidence >= hub_line):
        return WEAK_VIEW
    if best < lock or held < confirm or 0 < stuck <= kept:
        return NO_TRAJECTORY
    return AMBIGUOUS if own_uniqueness < unique else LOCKED


@dataclass(frozen=True)
class LockRules:
    """The lock's rules' parameters (``matchers.params.STREAM_RULES``: their defaults and meanings): ``lock``,
    ``evidence``, ``evidence_decay``, ``hub``, ``unique``, ``confirm``, ``stuck``, ``trust``, ``hold``, and
    ``rival_window``: places either side of the answer that a rival trajectory must lie beyond."""

    lock: float
    evidence: float
    evidence_decay: float
    hub: float
    unique: float
    confirm: int
    stuck: int
    trust: float
    hold: float
    rival_window: int

    def __post_init__(self) -> None:
        if not 0.0 <= self.evidence_decay < 1.0:
            raise ValueError(f"evidence_decay must be in [0, 1), got {self.evidence_decay}")
        if not 0.0 <= self.unique < 1.0:
            raise ValueError(f"unique must be in [0, 1), got {self.unique}")
        if int(self.confirm) < 1:
            raise ValueError(f"confirm must be at least 1, got {self.confirm}")
        if int(self.stuck) < 0:
            raise ValueError(f"stuck must be at least 0 (0: off), got {self.stuck}")
        if not 0.0 < self.trust <= 1.0:
            raise ValueError(f"trust must be in (0, 1] (1: off), got {self.trust}")


class LockVerdict:
    """The lock's rules over a stream (module docstring) on the map's drives ``graph``, with parameters
    ``rules``."""

    def __init__(self, graph: RouteGraph, rules: LockRules) -> None:
        self.graph, self.rules = graph, rules
        self.reset()

    def reset(self) -> None:
        self._evidence: float | None = None   # the answer's recent standing out of its rows
        self._hub: float | None = None        # the same, less its place's mean over the stream's recent frames
        # this stream's views per place
        self._recent = RecentViews(self.graph.n_refs) if self.rules.hub > OFF else None
        self._prev: int | None = None   # the frame before's answer
        self._held = 0                    # frames the answer's place has held, this one included
        self._anchor: int | None = None   # where the answer's place last moved on to
        self._kept = 0                    # frames the camera moved since, the answer kept there

    def judge(self, f: FrameReading) -> Judgement:
        graph, n_refs, r = self.graph, self.graph.n_refs, self.rules
        near = graph.near(f.ref, r.rival_window)
        rival = max_outside(f.values, f.where, near)
        here = (float(answer_view(graph, f.ref, f.where, f.part).max()) - f.mean) / f.std
        self._evidence = evidence_average(self._evidence, here, r.evidence_decay, f.standing)
        if self._recent is not None:   # a standing camera or a stopped trajectory repeats one place: no hub
            repeats = f.standing or f.stopped
            views = self._recent.read(f.z, f.places, learn=not repeats)
            hub_view = float(answer_view(graph, f.ref, f.where, views).max())
            self._hub = evidence_average(self._hub, hub_view, r.evidence_decay, repeats)
        # the rule asks for an answer unambiguous along its own drive: another drive may be the same road
        # driven again, whose places are no rival to it
        first, last = graph.bounds(f.ref)
        own = rival if (first, last) == (0, n_refs - 1) else max_outside(
            f.values, f.where, merge([*near, (0, first), (last + 1, n_refs)]))
        self._held = 1 if place_jumped(graph, self._prev, f.ref, r.rival_window) else self._held + 1
        self._prev = f.ref
        if place_advanced(graph, self._anchor, f.ref):
            self._anchor, self._kept = f.ref, 0
        elif f.cued and not f.standing:   # the cue says the camera moved (without a cue nothing says so)
            self._kept += 1
        why = lock_verdict(self._evidence, f.best, uniqueness(own, f.best), r.evidence, r.lock, r.unique,
                           np.inf if self._hub is None else self._hub, r.hub, self._held, int(r.confirm), self._kept,
                           int(r.stuck), float(r.trust))
        return Judgement(float(why == LOCKED) + uniqueness(rival, f.best), f.best >= r.hold * r.lock, why)
