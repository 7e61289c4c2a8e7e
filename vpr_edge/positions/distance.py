"""Distances between positions in metres: Euclidean for ``local`` x, y; great-circle (haversine) for
``wgs84`` latitude, longitude in degrees."""
from __future__ import annotations

import numpy as np

EARTH_RADIUS_M = 6_371_008.8


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
