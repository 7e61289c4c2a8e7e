"""Whole-route similarities for one frame at a fraction of the cost: signs first, exact values where they count.

A local search (``stream-rules``) still searches the whole route on some frames: its periodic check, and every
frame while lost or not firmly locked. On a large map those frames read every stored encoding (100,000 x
2,048 int8: 205 MB, 62 ms on one core). ``CoarseSearch`` keeps the signs of the stored encodings (one bit a
dimension: an eighth of int8's bytes) and per frame:

1. estimates every reference's similarity from the Hamming distance between its signs and the query's
   (``agreement`` = 1 - 2 * distance / D: the share of dimensions whose signs agree, minus those that differ);
2. computes exact similarities for the ``keep`` references it ranks highest and for a fixed random sample
   of ``calib`` references;
3. puts the estimates on the exact scale (a line that gives them the sample's exact mean and spread: a
   least-squares line would shrink them towards the mean by their correlation, and the matcher z-scores
   each row by its mean and spread), and the exact values in place of the estimates where it has them.

The row it returns has exact values at the candidates that decide the match and calibrated estimates
elsewhere (which feed the matcher's per-frame mean and spread and its trajectories' background).
"""
from __future__ import annotations

import numpy as np

from vpr_edge.index.encodings import Encodings

COARSE_MIN_REFS = 20_000   # Localizer engages it on maps at least this long (shorter ones: exact is cheap)
SIGN_BLOCK = 8192          # references per block of the Hamming pass (scratch ~ 2 MB at 2,048 dims)


def pack_signs(x: np.ndarray) -> np.ndarray:
    """(R, D) values -> (R, W) uint64: bit d of row r set where x[r, d] > 0, D padded to W * 64 with zeros."""
    bits = np.packbits(np.asarray(x) > 0, axis=-1)
    pad = (-bits.shape[-1]) % 8
    if pad:
        bits = np.concatenate([bits, np.zeros(bits.shape[:-1] + (pad,), np.uint8)], axis=-1)
    return np.ascontiguousarray(bits).view(np.uint64)


def sign_bytes(dim: int) -> int:
    """Bytes of one reference's signs, one bit a dimension (``pack_signs`` pads each row to 64 bits in RAM)."""
    return (dim + 7) // 8


def agreement(refs: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """Sign agreement (Q, R) of queries (Q, D) with references (R, D): 1 - 2 * Hamming / D over the signs as
    ``pack_signs`` sets them (what ``CoarseSearch`` ranks references by)."""
    signs, d = pack_signs(refs), np.shape(refs)[1]
    return np.stack([1.0 - 2.0 * hamming(signs, q) / d for q in pack_signs(queries)]).astype(np.float32)


def hamming(signs: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Packed signs (R, W) uint64 and one query's (W,) -> differing bits per reference (R,) int32, a block of
    SIGN_BLOCK references at a time."""
    out = np.empty(len(signs), np.int32)
    scratch = np.empty((min(len(signs), SIGN_BLOCK), signs.shape[1]), np.uint64)
    for i in range(0, len(signs), SIGN_BLOCK):
        block = signs[i:i + SIGN_BLOCK]
        b = scratch[:len(block)]
        np.bitwise_xor(block, q, out=b)
        np.bitwise_count(b, out=b)
        out[i:i + len(block)] = b.sum(axis=1)
    return out


class CoarseSearch:
    """Whole-route similarity rows of single queries against ``stored`` (``index.encodings.Encodings``, R x D):
    exact for the ``keep`` best by sign agreement and for ``calib`` fixed random references, sign agreement
    scaled to the sample's exact mean and spread elsewhere. Signs are packed on the first call (one pass
    over the stored encodings, whose pages a memory-mapped map then releases)."""

    def __init__(self, stored: Encodings, keep: int = 1024, calib: int = 512, seed: int = 0) -> None:
        r = stored.shape[0]
        self.stored = stored
        self.keep = max(1, min(keep, r))
        self.calib = np.sort(np.random.default_rng(seed).choice(r, min(calib, r), replace=False))
        self._signs: np.ndarray | None = None

    @property
    def signs(self) -> np.ndarray:
        """(R, W) uint64 packed signs of the stored encodings (built once, a block at a time)."""
        if self._signs is None:
            step = max(1, (8 << 20) // max(1, self.stored.shape[1]))
            self._signs = np.concatenate([pack_signs(block) for _, block in self.stored.blocks(step)])
        return self._signs

    def agreement(self, q: np.ndarray) -> np.ndarray:
        """Query (D,) -> sign agreement with every reference (R,) float32 in [-1, 1]."""
        d = self.stored.shape[1]
        return (1.0 - 2.0 * hamming(self.signs, pack_signs(q[None])[0]) / d).astype(np.float32)

    def similarity(self, q: np.ndarray) -> np.ndarray:
        """Query encoding (D,) -> (R,) float32: exact dot products at the sign-ranked top ``keep`` and the
        calibration sample; elsewhere the agreement mapped linearly to the sample's exact mean and spread."""
        q = np.asarray(q, np.float32)
        est = self.agreement(q)
        top = np.argpartition(-est, self.keep - 1)[: self.keep]
        rows = np.union1d(top, self.calib)
        exact = self.stored.similarity(q[None], rows)[0]
        at = np.searchsorted(rows, self.calib)
        x, y = est[self.calib].astype(np.float64), exact[at].astype(np.float64)
        slope = float(y.std() / x.std()) if x.std() > 0 else 0.0
        out = (slope * (est - x.mean()) + y.mean()).astype(np.float32)
        out[rows] = exact
        return out
