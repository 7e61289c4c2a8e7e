"""A map fitted to its route: a linear map of the encodings learned from labelled drives (``vpr-edge adapt``).

Each labelled frame is paired with its place's reference. The differences within the pairs span what the
drive's conditions change (snow, light, the camera) and not the place; the ``rank`` strongest directions of
those differences are whitened, shrunk towards the rest (Ledoit-Wolf style, ``shrink``):

    y = unit(x - B^T ((1 - keep) * (B x))),   keep_i = sqrt(l / (e_i + l)),   l = shrink * mean(e)

with ``B`` (rank, D) the differences' principal directions and ``e`` their variances. The map is D -> D
(identity outside ``B``), so the stored rows keep their size and storage. Keeping only the top directions of
between-place scatter (a full LDA) lost on nordland-dev: 400 places are too few to estimate them
(docs/usage.md, "Fitting vpr-edge to your route").

References are mapped once, when the map is adapted; each query encoding is mapped in ``PlaceMap.encode``,
so ``localize``, ``evaluate`` and the index all see mapped encodings. NumPy only.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vpr_edge.encoders.base import unit_rows

RANK = 20           # directions of within-place change whitened (chosen on an inner split of nordland-dev's first half)
SHRINK = 0.1        # their variances shrunk towards this share of the mean (0: whitened fully)
MIN_PAIRS = 50      # labelled frames a drive (or drives) must give to learn from
PAIRS_PER_RANK = 4  # at least this many pairs a direction: fewer pairs learn fewer directions


@dataclass(frozen=True)
class Adaptation:
    """The learned map (module docstring): ``basis`` (m, D) float32 orthonormal rows, ``keep`` (m,) float32 in
    (0, 1], what each direction keeps of its length."""

    basis: np.ndarray
    keep: np.ndarray

    @property
    def dim(self) -> int:
        return int(self.basis.shape[1])

    def apply(self, x: np.ndarray) -> np.ndarray:
        """Encodings (B, D) of any positive scale -> mapped unit encodings (B, D) float32 (a zero row stays
        zero)."""
        x = np.atleast_2d(np.asarray(x, np.float32))
        y = x - ((x @ self.basis.T) * (1.0 - self.keep)) @ self.basis
        norm = np.linalg.norm(y, axis=1, keepdims=True)
        return np.divide(y, norm, out=np.zeros_like(y), where=norm > 0).astype(np.float32)

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {"adapt_basis": self.basis.astype(np.float32), "adapt_keep": self.keep.astype(np.float32)}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], dim: int) -> "Adaptation":
        """From a map's ``adapt_basis`` and ``adapt_keep``; ValueError unless they fit ``dim`` dims, are finite,
        the rows orthonormal and ``keep`` in (0, 1]."""
        basis = np.array(arrays["adapt_basis"], np.float32)   # into RAM (a memory-mapped map)
        keep = np.array(arrays["adapt_keep"], np.float32)
        if basis.ndim != 2 or basis.shape[1] != dim or keep.shape != (basis.shape[0],) or not len(keep):
            raise ValueError(f"adaptation {basis.shape} and {keep.shape} do not fit {dim}-dim encodings")
        if not (np.isfinite(basis).all() and np.isfinite(keep).all()) or (keep <= 0).any() or (keep > 1).any():
            raise ValueError("adaptation holds non-finite values, or keeps outside (0, 1]")
        if np.abs(basis @ basis.T - np.eye(len(keep), dtype=np.float32)).max() > 1e-3:
            raise ValueError("adaptation's directions are not orthonormal")
        return cls(basis, keep)


def middle_refs(truth: np.ndarray) -> np.ndarray:
    """Padded ground truth (Q, T) (-1: none) -> each frame's one reference to pair with (Q,) int64: the middle
    of its sorted true references (-1: a frame of no place)."""
    t = np.sort(np.where(np.asarray(truth) < 0, np.iinfo(np.int64).max, truth).astype(np.int64), axis=1)
    count = (np.asarray(truth) >= 0).sum(axis=1)
    mid = t[np.arange(len(t)), np.maximum(count - 1, 0) // 2]
    return np.where(count > 0, mid, -1)


def rank_for(pairs: int, rank: int = RANK) -> int:
    """The directions learned from ``pairs`` labelled frames: ``rank``, fewer where pairs are few."""
    return max(1, min(rank, pairs // PAIRS_PER_RANK))


def fit_within_place(queries: np.ndarray, refs: np.ndarray, rank: int = RANK, shrink: float = SHRINK
                     ) -> Adaptation:
    """Labelled frames' encodings ``queries`` (N, D) and their places' references ``refs`` (N, D), row by row
    (any positive scale: each row is made unit) -> the within-place whitening (module docstring) of the
    ``rank_for(N, rank)`` strongest directions. ValueError for no pairs or ``shrink`` <= 0."""
    q, r = unit_rows(queries), unit_rows(refs)
    if q.shape != r.shape or not len(q):
        raise ValueError(f"need matching pairs, got {q.shape} and {r.shape}")
    if shrink <= 0:
        raise ValueError(f"shrink must be > 0, got {shrink}")
    diff = q - r
    _, s, vt = np.linalg.svd(diff, full_matrices=False)
    var = s ** 2 / len(diff)
    m = min(rank_for(len(diff), rank), int((var > 0).sum()) or 1)
    floor = shrink * float(var.mean()) if var.any() else 1.0
    keep = np.sqrt(floor / (var[:m] + floor))
    return Adaptation(vt[:m].astype(np.float32), keep.astype(np.float32))
