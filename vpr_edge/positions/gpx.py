"""Positions from a GPX track (``gpxpy``, the ``geo`` extra), matched to the frames by time."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from vpr_edge.errors import VprError
from vpr_edge.positions.fill import at_times
from vpr_edge.positions.model import Positions


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
