"""The ``stream-rules`` matcher's parameters (``road.RoadMatcher``), checked once: ``StreamConfig``, in three groups,
the trajectories' model, the search and the lock's rules (``lock.LockRules``). Their defaults and meanings are
``params.STREAM_RULES``'s, defined there only: ``StreamConfig.of(params)`` reads a parameter dict (the registry's),
``StreamConfig.default()`` the defaults.
"""
from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

from vpr_edge.matchers.lock import LockRules
from vpr_edge.matchers.params import STREAM_RULES, defaults


@dataclass(frozen=True)
class TrajectoryModel:
    """How trajectories are scored: the motion model (``vmax``, ``grid``, ``turn``, ``decay``), the frame's
    evidence (``bias``, ``memory`` of the hub means), the stop rules without a motion cue (``stop_gain``,
    ``stop_decay``) and the motion cue (``still``; ``still_memory`` is read where the cue is computed,
    ``Matcher.motion_cue``)."""

    vmax: float
    grid: int
    decay: float
    bias: float
    turn: float
    memory: float
    stop_gain: float
    stop_decay: float
    still: float
    still_memory: int


@dataclass(frozen=True)
class SearchConfig:
    """Which places a frame searches: the local search around a firm lock (``window``, ``probe``, ``check``,
    ``span``) and, on a map with an index, around its candidates (``seek``, ``peaks``; ``seek_frames`` is read
    where the index is asked, ``index.ivf.SequenceQuery``)."""

    window: int
    probe: int
    check: int
    span: int
    seek: int
    peaks: int
    seek_frames: int


GROUPS = (TrajectoryModel, SearchConfig, LockRules)


@dataclass(frozen=True)
class StreamConfig:
    """Every ``params.STREAM_RULES`` parameter, by group: ``model``, ``search``, ``rules``. The lock's rules are
    checked by ``LockRules``, the rest here."""

    model: TrajectoryModel
    search: SearchConfig
    rules: LockRules

    def __post_init__(self) -> None:
        m, s = self.model, self.search
        if not 0.0 < m.decay < 1.0:
            raise ValueError(f"decay must be in (0, 1), got {m.decay}")
        if not (0.0 <= m.stop_gain <= 1.0 and 0.0 < m.stop_decay < 1.0):
            raise ValueError(f"need stop_gain in [0, 1] and stop_decay in (0, 1), got {m.stop_gain}, {m.stop_decay}")
        if not 0.0 <= m.still <= 1.0:
            raise ValueError(f"still must be in [0, 1] (0: no motion cue), got {m.still}")
        if m.grid < 1 or m.vmax < 0 or m.memory < 1 or s.window < 0 or s.probe < 2:
            raise ValueError(f"need grid >= 1, vmax >= 0, memory >= 1, window >= 0, probe >= 2 (got {m.grid}, "
                             f"{m.vmax}, {m.memory}, {s.window}, {s.probe})")

    @classmethod
    def of(cls, params: dict[str, Any]) -> StreamConfig:
        """The configuration from a parameter dict (``params.STREAM_RULES``'s names); keys it does not hold are
        ignored, a missing one is a TypeError."""
        return cls(*(group(**{f.name: params[f.name] for f in fields(group) if f.name in params})
                     for group in GROUPS))

    @classmethod
    def default(cls) -> StreamConfig:
        """The configuration of ``params.STREAM_RULES``'s defaults."""
        return cls.of(defaults(STREAM_RULES))

    def params(self) -> dict[str, Any]:
        """The parameter dict it was read from (``of``'s inverse)."""
        return {f.name: getattr(group, f.name) for group in (self.model, self.search, self.rules)
                for f in fields(group)}
