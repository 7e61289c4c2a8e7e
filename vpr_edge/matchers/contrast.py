"""Similarity normalisation shared by the sequence matchers."""
from __future__ import annotations

import numpy as np


def local_contrast(sim: np.ndarray, window: int) -> np.ndarray:
    """SeqSLAM's local contrast enhancement, on similarities: each value of ``sim`` (..., R) z-scored against
    the values of the same frame at references within +-``window``//2 of it (the window clipped at the ends
    of the route). Returns float64 (..., R), higher = more alike than the neighbourhood. Moving sums by
    cumulative sums: O(R) per frame."""
    s = np.asarray(sim, np.float64)
    r = s.shape[-1]
    half = max(1, window // 2)
    zero = np.zeros(s.shape[:-1] + (1,))
    c1 = np.concatenate([zero, np.cumsum(s, axis=-1)], axis=-1)
    c2 = np.concatenate([zero, np.cumsum(s * s, axis=-1)], axis=-1)
    idx = np.arange(r)
    lo, hi = np.maximum(idx - half, 0), np.minimum(idx + half + 1, r)
    n = hi - lo
    mean = (c1[..., hi] - c1[..., lo]) / n
    var = np.maximum((c2[..., hi] - c2[..., lo]) / n - mean * mean, 0.0)
    return (s - mean) / np.sqrt(var + 1e-12)
