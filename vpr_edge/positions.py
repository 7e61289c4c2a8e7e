"""Where the reference places are: positions of a route, read from a CSV file or the images' EXIF GPS tags,
stored in a map, interpolated between references, measured in metres.

Two frames, never mixed: ``local`` (x, y in metres, e.g. odometry) and ``wgs84`` (latitude, longitude in
degrees, e.g. GPS). Heading is in degrees, clockwise from north (wgs84) or from the +y axis (local); altitude
in metres; NaN where unknown. Distances are Euclidean (local) or great-circle (haversine, wgs84).
"""
from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from vpr_edge.errors import VprError, warn
from vpr_edge.files import read_csv_rows

EARTH_RADIUS_M = 6_371_008.8
FRAMES = {"local": ("x", "y"), "wgs84": ("lat", "lon")}
_NAME_COLUMNS = ("name", "frame", "file", "image")
_ALTITUDE = ("z", "alt", "altitude")


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


def distances(a: np.ndarray, b: np.ndarray, geo: bool) -> np.ndarray:
    """(A, 2) x (B, 2) -> (A, B) metres: haversine for lat/lon degrees, Euclidean for x/y."""
    if not geo:
        return np.sqrt(((a[:, None, :] - b[None, :, :]) ** 2).sum(-1))
    return _haversine(np.radians(a)[:, None, :], np.radians(b)[None, :, :])


def paired_distances(a: np.ndarray, b: np.ndarray, geo: bool) -> np.ndarray:
    """(N, 2) and (N, 2) -> (N,) metres between a[i] and b[i]."""
    if not geo:
        return np.sqrt(((a - b) ** 2).sum(-1))
    return _haversine(np.radians(a), np.radians(b))


def _haversine(la: np.ndarray, lb: np.ndarray) -> np.ndarray:
    dlat, dlon = lb[..., 0] - la[..., 0], lb[..., 1] - la[..., 1]
    h = np.sin(dlat / 2) ** 2 + np.cos(la[..., 0]) * np.cos(lb[..., 0]) * np.sin(dlon / 2) ** 2
    return 2 * EARTH_RADIUS_M * np.arcsin(np.sqrt(np.clip(h, 0.0, 1.0)))


def _number(text: str, path: Path, line: int, column: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise VprError(f"{path}: line {line}: {column} {text!r} is not a number") from None
    if not np.isfinite(value):
        raise VprError(f"{path}: line {line}: {column} is not finite")
    return value


def read_csv(path: str | os.PathLike[str], names: Sequence[str] | None = None) -> Positions:
    """Positions from a CSV file with a header: ``x,y`` (metres) or ``lat,lon`` (degrees), optionally ``z`` /
    ``alt`` and ``heading``, and optionally a ``name`` (or ``frame``, ``file``, ``image``) column naming each
    row's reference image. Given ``names`` (the references, in map order), rows are matched by name, or in
    order when there is no name column (then there must be one row per reference). A row with empty
    coordinates, or a reference no row names, has no fix: it is interpolated along the route's order between
    the fixes either side (with a warning); one before the first fix or after the last is an error."""
    path = Path(path)
    rows = read_csv_rows(path, "positions")
    head = [c.strip().lower() for c in rows[0][1]] if rows else []
    found = [frame for frame, cols in FRAMES.items() if all(c in head for c in cols)]
    if len(found) != 1:
        raise VprError(f"{path}: positions need columns x,y (metres) or lat,lon (degrees) in the header"
                       + (", not both (positions in two frames)" if len(found) > 1 else ""))
    frame = found[0]
    ix = [head.index(c) for c in FRAMES[frame]]
    extra = {"heading": next((head.index(c) for c in ("heading", "yaw") if c in head), None),
             "altitude": next((head.index(c) for c in _ALTITUDE if c in head), None)}
    name_col = next((head.index(c) for c in _NAME_COLUMNS if c in head), None)
    body = rows[1:]   # "," is a row without a fix
    if not body:
        raise VprError(f"{path}: no positions")
    count = len(names) if names is not None else len(body)
    if names is not None and name_col is None and len(body) != count:
        raise VprError(f"{path}: {len(body)} positions but {count} references (give one row per reference, in "
                       f"order, or a name column)")
    coords = np.full((count, 2), np.nan)
    heading, altitude = np.full(count, np.nan), np.full(count, np.nan)
    where = {name: i for i, name in enumerate(names)} if names is not None and name_col is not None else None
    for k, (line, row) in enumerate(body):
        cells = row + [""] * (len(head) - len(row))
        if where is not None:
            name = cells[name_col].strip()
            if name not in where:
                raise VprError(f"{path}: line {line}: {name!r} is not one of the references")
            i = where[name]
        else:
            i = k
        text = [cells[j].strip() for j in ix]
        if all(text):
            coords[i] = [_number(t, path, line, c) for t, c in zip(text, FRAMES[frame])]
        elif any(text):
            raise VprError(f"{path}: line {line}: give both {' and '.join(FRAMES[frame])}, or neither (no fix)")
        for key, j in extra.items():
            if j is not None and cells[j].strip():
                (heading if key == "heading" else altitude)[i] = _number(cells[j].strip(), path, line, key)
    try:
        check_range(coords[np.isfinite(coords).all(axis=1)], frame, str(path))
    except ValueError as e:
        raise VprError(str(e)) from None
    return _filled(coords, frame, heading % 360.0, altitude, str(path))


def _filled(coords: np.ndarray, frame: str, heading: np.ndarray, altitude: np.ndarray, where: str) -> Positions:
    """Positions with the references that have no fix interpolated by their order between the fixes either
    side (VprError if one lies before the first fix or after the last)."""
    have = np.isfinite(coords).all(axis=1)
    if not have.any():
        raise VprError(f"{where}: no reference has a position")
    missing = int((~have).sum())
    if missing:
        known = np.flatnonzero(have)
        if not have[0] or not have[-1]:
            raise VprError(f"{where}: references before the first position or after the last cannot be "
                           f"placed (first fix: reference {known[0]}, last: {known[-1]}, of {len(have)})")
        idx = np.arange(len(have))
        coords = np.stack([np.interp(idx, known, coords[known, c]) for c in range(2)], axis=1)
        warn(f"{where}: {missing} of {len(have)} references have no position; placed between the fixes either "
             f"side by their order in the route")
    return Positions(coords, frame, heading, altitude, missing)


def from_exif(files: Sequence[Path]) -> Positions:
    """Positions from the reference images' EXIF GPS tags (GPSLatitude/Longitude with their N/S, E/W refs,
    GPSAltitude, GPSImgDirection), read with ``exifread`` (the ``geo`` extra). Images without a fix are
    interpolated between those with one (with a warning)."""
    try:
        import exifread
    except ImportError:
        raise VprError("--positions exif needs exifread: pip install 'vpr-edge[geo]'") from None
    coords = np.full((len(files), 2), np.nan)
    heading, altitude = np.full(len(files), np.nan), np.full(len(files), np.nan)

    def value(tag) -> float:
        parts = [float(v.num) / float(v.den) if getattr(v, "den", 1) else float("nan") for v in tag.values]
        return parts[0] + parts[1] / 60 + parts[2] / 3600 if len(parts) == 3 else parts[0]

    for i, f in enumerate(files):
        try:
            with open(f, "rb") as fh:
                tags = exifread.process_file(fh, details=False)
        except (OSError, ValueError, KeyError, IndexError, TypeError):
            continue
        lat, lon = tags.get("GPS GPSLatitude"), tags.get("GPS GPSLongitude")
        if lat is None or lon is None:
            continue
        sign_lat = -1.0 if str(tags.get("GPS GPSLatitudeRef", "N")).strip().upper().startswith("S") else 1.0
        sign_lon = -1.0 if str(tags.get("GPS GPSLongitudeRef", "E")).strip().upper().startswith("W") else 1.0
        coords[i] = [sign_lat * value(lat), sign_lon * value(lon)]
        if "GPS GPSAltitude" in tags:
            altitude[i] = value(tags["GPS GPSAltitude"])
        if "GPS GPSImgDirection" in tags:
            heading[i] = value(tags["GPS GPSImgDirection"]) % 360.0
    where = str(Path(files[0]).parent) if files else "references"
    coords[~np.isfinite(coords).all(axis=1)] = np.nan
    return _filled(coords, "wgs84", heading, altitude, f"{where} (EXIF GPS)")


def require_gpxpy(path: str | os.PathLike[str]):
    """The gpxpy module, or VprError naming the extra that brings it (checked before any work)."""
    try:
        import gpxpy
    except ImportError:
        raise VprError(f"{path}: reading GPX needs gpxpy: pip install 'vpr-edge[geo]'") from None
    return gpxpy


def from_gpx(path: str | os.PathLike[str], stamps: np.ndarray) -> Positions:
    """Positions at the times ``stamps`` (Unix seconds) from a GPX track (every point of every track and
    segment with a time; ``gpxpy``, the ``geo`` extra): latitude, longitude and elevation interpolated
    linearly in time between the points either side (with a warning for those between points). VprError
    for a file that does not parse, a track without timed points, or a stamp outside the track's time."""
    path = Path(path)
    gpxpy = require_gpxpy(path)
    try:
        with open(path) as f:
            gpx = gpxpy.parse(f)
    except (OSError, UnicodeDecodeError) as e:
        raise VprError(f"{path}: cannot read the GPX track ({getattr(e, 'strerror', None) or e})") from None
    except Exception as e:   # gpxpy raises its own GPXException and XML errors
        raise VprError(f"{path}: not a readable GPX track ({str(e).splitlines()[0][:100]})") from None
    points = [(p.time.timestamp(), p.latitude, p.longitude, np.nan if p.elevation is None else p.elevation)
              for track in gpx.tracks for seg in track.segments for p in seg.points if p.time is not None]
    if not points:
        raise VprError(f"{path}: no track point with a time (a GPX track is matched to frames by time)")
    fix = np.array([p + (np.nan,) for p in sorted(points)], np.float64)
    return at_times(fix, stamps, "wgs84", str(path), "the track")


def at_times(fix: np.ndarray, stamps: np.ndarray, frame: str, where: str, source: str) -> Positions:
    """Positions at the times ``stamps`` (N,) seconds from time-ordered fixes ``fix`` (M, 5): time (s), the
    two coordinates, altitude, heading (degrees; NaN unknown): each linearly interpolated in time between the
    fixes either side (heading the short way round, only where every fix has one), with a warning for the
    frames that fall between fixes. VprError naming ``where`` for a frame outside ``source``'s time span or
    coordinates out of range."""
    if stamps.min() < fix[0, 0] - 1e-6 or stamps.max() > fix[-1, 0] + 1e-6:
        raise VprError(f"{where}: the frames span {stamps.min():.3f} to {stamps.max():.3f} s but {source} only "
                       f"{fix[0, 0]:.3f} to {fix[-1, 0]:.3f} s")
    coords = np.stack([np.interp(stamps, fix[:, 0], fix[:, k]) for k in (1, 2)], axis=1)
    altitude = np.interp(stamps, fix[:, 0], fix[:, 3])
    heading = np.full(len(stamps), np.nan)
    if np.isfinite(fix[:, 4]).all():
        heading = np.interp(stamps, fix[:, 0], np.degrees(np.unwrap(np.radians(fix[:, 4])))) % 360.0
    try:
        check_range(coords, frame, f"{where} ({source})")
    except ValueError as e:
        raise VprError(str(e)) from None
    between = int((~np.isin(np.round(stamps, 6), np.round(fix[:, 0], 6))).sum())
    if between:
        warn(f"{where}: {between} of {len(stamps)} frames fall between the fixes of {source}; their positions "
             f"are interpolated in time")
    return Positions(coords, frame, heading, altitude, between)
