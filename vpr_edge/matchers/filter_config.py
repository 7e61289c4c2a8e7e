"""The ``stream`` matcher's parameters (``bayes``), checked once; their defaults and meanings are
``params.STREAM``."""
from __future__ import annotations

from dataclasses import dataclass, fields


@dataclass(frozen=True)
class FilterConfig:
    """The filter's parameters (``params.STREAM``: their defaults and meanings). ``still_memory`` and
    ``seek_frames`` are read where the motion cue and the index query are made."""

    vmax: int
    speed_step: float
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
    window: int
    probe: int
    check: int
    span: int
    hold: float
    seek: int
    peaks: int

    def __post_init__(self) -> None:
        for name in ("speed_change", "leave", "enter", "jump"):
            if not 0.0 <= getattr(self, name) < 0.5:
                raise ValueError(f"{name} must lie in [0, 0.5), got {getattr(self, name)}")
        bad_step = ValueError(f"speed_step must be 1, 0.5 or 0.25 and divide vmax - 1, got {self.speed_step} for "
                              f"vmax {self.vmax}")
        if self.speed_step not in (1.0, 0.5, 0.25):   # a speed's cycle of whole places: at most 4 frames
            raise bad_step
        steps = max(self.vmax - 1, 0) / self.speed_step   # speeds above one place a frame
        if abs(steps - round(steps)) > 1e-9:
            raise bad_step
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
        if self.window < 0 or self.probe < 1 or self.check < 1 or not 0 <= self.span <= self.check:
            raise ValueError(f"need window >= 0, probe >= 1, check >= 1 and 0 <= span <= check (got {self.window}, "
                             f"{self.probe}, {self.check}, {self.span})")
        if self.seek < 0 or self.peaks < 1:
            raise ValueError(f"need seek >= 0 and peaks >= 1 (got {self.seek}, {self.peaks})")
        if not 0.0 < self.hold <= 1.0:
            raise ValueError(f"hold must lie in (0, 1], got {self.hold}")

    @classmethod
    def of(cls, params: dict) -> "FilterConfig":
        """The configuration from a parameter dict; keys it does not hold are ignored."""
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in params.items() if k in names})
