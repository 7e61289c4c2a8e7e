"""Similarity between query and reference descriptors: (Q, D) x (R, D) -> (Q, R), higher = more alike."""
from __future__ import annotations

import numpy as np


def cosine_similarity(queries: np.ndarray, refs: np.ndarray) -> np.ndarray:
    """(Q, D) and (R, D) -> (Q, R) cosine similarities in [-1, 1] (rows of zeros give 0)."""
    q = queries / np.maximum(np.linalg.norm(queries, axis=1, keepdims=True), 1e-12)
    r = refs / np.maximum(np.linalg.norm(refs, axis=1, keepdims=True), 1e-12)
    return q @ r.T
