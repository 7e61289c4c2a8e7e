"""A route's positions (``Positions``): one per reference place, stored in a map, interpolated between
references, measured in metres (``positions.distance``).

Two frames, never mixed: ``local`` (x, y in metres, e.g. odometry) and ``wgs84`` (latitude, longitude in
degrees, e.g. GPS). Heading is in degrees, clockwise from north (wgs84) or from the +y axis (local); altitude
in metres; NaN where unknown.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from vpr_edge.errors import VprError
from vpr_edge.positions.distance import paired_distances

FRAMES = {"local": ("x", "y"), "wgs84": ("lat", "lon")}


@dataclass(frozen=True)
class Positions:
    """``coords`` (R, 2) float64 in ``frame`` (``FRAMES``: x, y metres or lat, lon degrees), ``heading`` and
    ``altitude`` (R,) float64, NaN where unknown; ``interpolated``: how many were filled between fixes."""

    coords: np.ndarray
    frame: str
    heading: np.ndarray
    altitude: np.ndarray
    interpolated: int = 0

    def __len__(self) -> int:
        return len(self.coords)

    @property
    def geo(self) -> bool:
        return self.frame == "wgs84"

    def steps(self) -> np.ndarray:
        """(R - 1,) metres between consecutive references."""
        return paired_distances(self.coords[:-1], self.coords[1:], self.geo)

    def along(self) -> np.ndarray:
        """(R,) metres along the route from its first reference (computed once: ``at`` reads it per frame)."""
        return self._along

    @cached_property
    def _along(self) -> np.ndarray:
        return np.concatenate([[0.0], np.cumsum(self.steps())])

    def at(self, index: float) -> tuple[np.ndarray, float, float]:
        """The position at a fractional reference ``index`` (between references: linear in the coordinates,
        which is exact to millimetres over the spacing of a route's references) -> (coords (2,), heading
        degrees or NaN, metres along the route)."""
        i = int(np.clip(np.floor(index), 0, len(self) - 1))
        j = min(i + 1, len(self) - 1)
        t = float(np.clip(index - i, 0.0, 1.0)) if j > i else 0.0
        coords = (1 - t) * self.coords[i] + t * self.coords[j]
        a, b = self.heading[i], self.heading[j]
        heading = float(a if t < 0.5 else b) if np.isnan(a) or np.isnan(b) else \
            float((a + t * ((b - a + 180.0) % 360.0 - 180.0)) % 360.0)
        along = self._along
        return coords, heading, float((1 - t) * along[i] + t * along[j])

    def check_frame(self, other: "Positions", where: str, whose: str = "the map's") -> None:
        """VprError naming ``where`` unless ``other`` is in this frame (x,y metres or lat,lon degrees): the
        one rule for positions given against a map's, a ground truth's or appended references'."""
        if other.frame != self.frame:
            raise VprError(f"{where}: positions in two frames: {whose} are {self.frame} "
                           f"({','.join(FRAMES[self.frame])}), these {other.frame} ({','.join(FRAMES[other.frame])})")

    def concat(self, more: "Positions") -> "Positions":
        """These references' positions, then ``more``'s (VprError if they are in another frame)."""
        self.check_frame(more, "appended references")
        return Positions(np.concatenate([self.coords, more.coords]), self.frame,
                         np.concatenate([self.heading, more.heading]), np.concatenate([self.altitude, more.altitude]),
                         self.interpolated + more.interpolated)

    def summary(self) -> dict:
        """What ``vpr-edge info`` shows: frame, route length in metres, extent (min and max per coordinate)."""
        names = FRAMES[self.frame]
        lo, hi = self.coords.min(axis=0), self.coords.max(axis=0)
        return {"frame": self.frame, "length_m": round(float(self.steps().sum()), 2),
                "extent": {names[0]: [float(lo[0]), float(hi[0])], names[1]: [float(lo[1]), float(hi[1])]},
                "heading": bool(np.isfinite(self.heading).any()), "interpolated": self.interpolated}

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {"positions": self.coords, "positions_heading": self.heading, "positions_altitude": self.altitude}

    def meta(self) -> dict:
        return {"frame": self.frame, "interpolated": self.interpolated}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], meta: dict, n_refs: int) -> "Positions":
        """The positions a map stores; ValueError if they do not fit its ``n_refs`` references or are not finite."""
        frame = meta.get("frame")
        if frame not in FRAMES:
            raise ValueError(f"positions frame {frame!r} is not one of {', '.join(FRAMES)}")
        coords = np.asarray(arrays["positions"], np.float64)
        heading = np.asarray(arrays["positions_heading"], np.float64)
        altitude = np.asarray(arrays["positions_altitude"], np.float64)
        if coords.shape != (n_refs, 2) or heading.shape != (n_refs,) or altitude.shape != (n_refs,):
            raise ValueError(f"positions do not fit the {n_refs} references")
        if not np.isfinite(coords).all():
            raise ValueError("positions hold NaN or infinite coordinates")
        check_range(coords, frame)
        return cls(coords, frame, heading, altitude, int(meta.get("interpolated", 0)))


def check_range(coords: np.ndarray, frame: str, where: str = "positions") -> None:
    """ValueError for latitudes outside [-90, 90] or longitudes outside [-180, 180]."""
    if frame == "wgs84" and ((np.abs(coords[:, 0]) > 90).any() or (np.abs(coords[:, 1]) > 180).any()):
        raise ValueError(f"{where}: latitude outside [-90, 90] or longitude outside [-180, 180]")
