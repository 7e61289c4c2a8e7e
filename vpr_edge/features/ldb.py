"""Local Difference Binary (Yang & Cheng 2012), as the thesis uses it: one binary descriptor per image.

The grey image is resized to ``size`` x ``size`` (or to ``patches`` x ``patches`` tiles of that size, each
its own descriptor). At every grid level l (an l x l grid of cells) each cell gets three values: its mean
intensity, and its x and y gradients (mean of the right half minus the left half, bottom minus top, all box
sums from one integral image). Every pair of cells of a level is compared on each value: bit = value_i >
value_j. Levels 2-5 give 3 * (6 + 36 + 120 + 300) = 1386 bits, of which ``n_bits`` are kept: chosen on the
reference images either at random or by entropy (bits nearest to half set first, skipping those correlated
above a bound with the chosen ones, the bound relaxed until enough are found, as ORB chooses its tests).

Bits are returned as +-1 floats: the cosine of two such vectors is 1 - 2 * Hamming / n_bits, so matching by
cosine ranks references exactly as matching by Hamming distance.

No well-kept library implements LDB (OpenCV's contrib has only a different, ORB-like "LDB"); this is
written here, vectorised over images and cells, and tested against a plain loop (tests/test_features.py).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from vpr_edge.features.base import Handcrafted, grey

LEVELS = (2, 3, 4, 5)


def cell_values(img: np.ndarray, level: int) -> np.ndarray:
    """(B, S, S) float64 grey -> (B, level*level, 3): per cell (row-major) mean intensity, x gradient
    (right half mean - left half mean), y gradient (bottom half mean - top half mean)."""
    b, s, _ = img.shape
    ii = np.zeros((b, s + 1, s + 1))
    ii[:, 1:, 1:] = img.cumsum(1).cumsum(2)
    edges = np.linspace(0, s, level + 1).round().astype(int)
    y0, x0 = np.meshgrid(edges[:-1], edges[:-1], indexing="ij")
    y1, x1 = np.meshgrid(edges[1:], edges[1:], indexing="ij")
    y0, x0, y1, x1 = (a.reshape(-1) for a in (y0, x0, y1, x1))
    ym, xm = (y0 + y1) // 2, (x0 + x1) // 2

    def mean(ya: np.ndarray, yb: np.ndarray, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
        area = np.maximum((yb - ya) * (xb - xa), 1)
        return (ii[:, yb, xb] - ii[:, ya, xb] - ii[:, yb, xa] + ii[:, ya, xa]) / area

    intensity = mean(y0, y1, x0, x1)
    dx = mean(y0, y1, xm, x1) - mean(y0, y1, x0, xm)
    dy = mean(ym, y1, x0, x1) - mean(y0, ym, x0, x1)
    return np.stack([intensity, dx, dy], axis=2)


def all_bits(img: np.ndarray, levels: Sequence[int] = LEVELS) -> np.ndarray:
    """(B, S, S) grey -> (B, L) bool: for each level, each cell pair i < j (row-major), each of the three
    values, value_i > value_j."""
    out = []
    for level in levels:
        v = cell_values(img, level)                                   # (B, C, 3)
        i, j = np.triu_indices(level * level, k=1)
        out.append((v[:, i, :] > v[:, j, :]).reshape(len(img), -1))   # pair-major, value-minor
    return np.concatenate(out, axis=1)


def select_bits(bits: np.ndarray, n_bits: int, method: str = "entropy", seed: int = 0) -> np.ndarray:
    """Choose ``n_bits`` columns of ``bits`` (n, L) bool -> sorted indices. ``entropy``: by |mean - 0.5|
    ascending, greedily skipping bits whose |correlation| with a chosen one exceeds a bound (0.2, raised by
    0.1 until enough are chosen); ``random``: uniformly at random."""
    n, total = bits.shape
    if n_bits >= total:
        return np.arange(total)
    if method == "random":
        return np.sort(np.random.default_rng(seed).choice(total, n_bits, replace=False))
    x = bits.astype(np.float64)
    p = x.mean(axis=0)
    sd = x.std(axis=0)
    centred = (x - p) / np.where(sd > 0, sd, 1.0)
    corr = np.abs(centred.T @ centred) / max(n, 1)
    corr[:, sd == 0] = 1.0                                             # constant bits carry nothing
    order = np.argsort(np.abs(p - 0.5), kind="stable")
    bound = 0.2
    while True:
        chosen: list[int] = []
        for c in order:
            if sd[c] > 0 and (not chosen or corr[c, chosen].max() <= bound):
                chosen.append(int(c))
                if len(chosen) == n_bits:
                    return np.sort(np.array(chosen))
        if bound >= 1.0:   # too few informative bits: fill with the most balanced of the rest
            rest = [int(c) for c in order if c not in set(chosen)]
            return np.sort(np.array(chosen + rest[: n_bits - len(chosen)]))
        bound += 0.1


@dataclass(frozen=True)
class Ldb(Handcrafted):
    """LDB front end. ``bits`` None: not fitted yet, ``local`` returns all L bits (build-map then calls
    ``fit`` on the references' and ``select``); otherwise the chosen bit indices (recorded in the map)."""

    size: int = 64
    patches: int = 1
    levels: tuple[int, ...] = LEVELS
    n_bits: int = 256
    selection: str = "entropy"
    bits: tuple[int, ...] | None = None
    name: str = field(default="ldb", init=False, repr=False)
    binary: bool = field(default=True, init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "levels", tuple(int(v) for v in self.levels))
        if self.bits is not None:
            object.__setattr__(self, "bits", tuple(int(v) for v in self.bits))

    @property
    def full_dim(self) -> int:
        return 3 * sum(lv * lv * (lv * lv - 1) // 2 for lv in self.levels)

    @property
    def needs_fit(self) -> bool:
        return self.bits is None

    @property
    def dim(self) -> int:
        return self.full_dim if self.bits is None else len(self.bits)

    @property
    def n_local(self) -> int:
        return self.patches * self.patches


    def describe(self) -> dict:
        return {"name": self.name, "params": {"size": self.size, "patches": self.patches, "levels": list(self.levels),
                                              "n_bits": self.n_bits, "selection": self.selection,
                                              "bits": None if self.bits is None else list(self.bits)}}

    def _tiles(self, images: Sequence[np.ndarray]) -> np.ndarray:
        s, p = self.size, self.patches
        g = np.stack([cv2.GaussianBlur(grey(im, (s * p, s * p)), (3, 3), 0) for im in images]).astype(np.float64)
        return g.reshape(len(images), p, s, p, s).transpose(0, 1, 3, 2, 4).reshape(-1, s, s)

    def local(self, images: Sequence[np.ndarray]) -> tuple[np.ndarray, None]:
        bits = all_bits(self._tiles(images), self.levels)
        if self.bits is not None:
            bits = bits[:, list(self.bits)]
        return (2.0 * bits - 1.0).astype(np.float32).reshape(len(images), self.n_local, -1), None

    def fit(self, local: np.ndarray, seed: int = 0) -> "Ldb":
        """Choose the bits on the references' full descriptors ``local`` (R, N, L) (+-1)."""
        chosen = select_bits(np.asarray(local).reshape(-1, local.shape[-1]) > 0, self.n_bits, self.selection, seed)
        return replace(self, bits=tuple(int(c) for c in chosen))

    def select(self, local: np.ndarray) -> np.ndarray:
        """Full descriptors (R, N, L) -> the chosen bits (R, N, n_bits)."""
        return np.asarray(local)[..., list(self.bits or ())]
