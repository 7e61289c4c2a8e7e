"""Ground truth for evaluation, from three sources, as a padded int array (Q, T): per query its correct
references, -1 as padding (a row of -1: the query's place is not in the map).

* the project's CSV: header ``query,references``, one row per query 0..Q-1, space-separated reference
  indices, an empty field for a place that is not in the map;
* a boolean (Q, R) ``.npy`` matrix, True where query and reference show the same place (VPR_Tutorial's
  GThard / GTsoft), read without pickle;
* positions: two CSV files (references, queries) with columns ``x,y`` (metres) or ``lat,lon`` (degrees);
  the correct references of a query are those within a radius in metres.
"""
from __future__ import annotations

import csv
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vpr_edge.errors import VprError

EARTH_RADIUS_M = 6_371_008.8


def pad(sets: Sequence[Sequence[int]]) -> np.ndarray:
    """Lists of reference indices -> (Q, T) int64 padded with -1 (T >= 1)."""
    width = max([len(s) for s in sets] + [1])
    out = np.full((len(sets), width), -1, np.int64)
    for q, s in enumerate(sets):
        out[q, : len(s)] = s
    return out


def load_csv(path: str | os.PathLike[str]) -> np.ndarray:
    """The project's ground-truth CSV -> (Q, T) padded truth."""
    try:
        with open(path, newline="") as f:
            rows = list(csv.reader(f))
    except (OSError, UnicodeDecodeError) as e:
        raise VprError(f"{path}: cannot read ground truth ({getattr(e, 'strerror', None) or e})") from None
    if not rows or [c.strip() for c in rows[0][:2]] != ["query", "references"]:
        raise VprError(f"{path}: not a ground-truth CSV (expected the header 'query,references')")
    out: dict[int, list[int]] = {}
    for n, row in enumerate(rows[1:], start=2):
        try:
            out[int(row[0])] = [int(v) for v in (row[1].split() if len(row) > 1 else [])]
        except ValueError:
            raise VprError(f"{path}: line {n}: expected 'query,ref ref ...'") from None
    if sorted(out) != list(range(len(out))) or not out:
        raise VprError(f"{path}: query indices must run 0..Q-1 without gaps")
    if any(v < 0 for refs in out.values() for v in refs):
        raise VprError(f"{path}: reference indices must be >= 0")
    return pad([out[i] for i in range(len(out))])


def load_matrix(path: str | os.PathLike[str]) -> np.ndarray:
    """A (Q, R) boolean ``.npy`` matrix -> (Q, T) padded truth."""
    try:
        m = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as e:
        raise VprError(f"{path}: not a readable .npy ground-truth matrix ({str(e).splitlines()[0][:100]})") from None
    if m.ndim != 2 or not (m.dtype == bool or np.issubdtype(m.dtype, np.integer)):
        raise VprError(f"{path}: ground-truth matrix must be 2-D boolean (queries x references), "
                       f"got {m.ndim}-D {m.dtype}")
    m = m.astype(bool)
    q, r = np.nonzero(m)
    return pad(np.split(r, np.cumsum(m.sum(axis=1))[:-1]))


def _read_positions(path: Path) -> tuple[np.ndarray, bool]:
    """(N, 2) positions and whether they are (lat, lon) degrees."""
    try:
        with open(path, newline="") as f:
            rows = list(csv.reader(f))
    except (OSError, UnicodeDecodeError) as e:
        raise VprError(f"{path}: cannot read positions ({getattr(e, 'strerror', None) or e})") from None
    head = [c.strip().lower() for c in rows[0]] if rows else []
    for cols, geo in ((("lat", "lon"), True), (("x", "y"), False)):
        if all(c in head for c in cols):
            ix = [head.index(c) for c in cols]
            break
    else:
        raise VprError(f"{path}: positions need columns x,y (metres) or lat,lon (degrees) in the header")
    try:
        pos = np.array([[float(row[i]) for i in ix] for row in rows[1:] if row], np.float64)
    except (ValueError, IndexError):
        raise VprError(f"{path}: positions must be numbers in every row") from None
    if len(pos) == 0 or not np.isfinite(pos).all():
        raise VprError(f"{path}: no positions, or a position that is not finite")
    return pos, geo


def _distances(a: np.ndarray, b: np.ndarray, geo: bool) -> np.ndarray:
    """(A, 2) x (B, 2) -> (A, B) metres: haversine for lat/lon degrees, Euclidean for x/y."""
    if not geo:
        return np.sqrt(((a[:, None, :] - b[None, :, :]) ** 2).sum(-1))
    la, lb = np.radians(a), np.radians(b)
    dlat = lb[None, :, 0] - la[:, None, 0]
    dlon = lb[None, :, 1] - la[:, None, 1]
    h = np.sin(dlat / 2) ** 2 + np.cos(la[:, None, 0]) * np.cos(lb[None, :, 0]) * np.sin(dlon / 2) ** 2
    return 2 * EARTH_RADIUS_M * np.arcsin(np.sqrt(np.clip(h, 0.0, 1.0)))


def from_positions(refs_csv: str | os.PathLike[str], queries_csv: str | os.PathLike[str],
                   radius_m: float, chunk: int = 512) -> np.ndarray:
    """References within ``radius_m`` metres of each query -> (Q, T) padded truth."""
    (rp, rgeo), (qp, qgeo) = _read_positions(Path(refs_csv)), _read_positions(Path(queries_csv))
    if rgeo != qgeo:
        raise VprError(f"{queries_csv}: positions must use the same columns as {refs_csv} (x,y or lat,lon)")
    sets: list[np.ndarray] = []
    for i in range(0, len(qp), chunk):
        near = _distances(qp[i:i + chunk], rp, rgeo) <= radius_m
        sets.extend(np.flatnonzero(row) for row in near)
    return pad(sets)
