"""Positions for every reference from fixes at some of them: between fixes by the references' order
(``by_order``: a CSV or EXIF tags with gaps) or by time (``at_times``: a GPX track, a bag's topic)."""
from __future__ import annotations

import numpy as np

from vpr_edge.errors import VprError, warn
from vpr_edge.positions.model import Positions, check_range


def by_order(coords: np.ndarray, frame: str, heading: np.ndarray, altitude: np.ndarray, where: str) -> Positions:
    """Positions with the references that have no fix (NaN rows of ``coords`` (R, 2)) interpolated by their
    order between the fixes either side, with a warning naming ``where`` (VprError if one lies before the
    first fix or after the last, or none has a fix)."""
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
