"""Ground truth and match accuracy for sequence pairs."""
from __future__ import annotations

import csv
import os

import numpy as np

from vpr_edge.errors import VprError


def load_ground_truth(path: str | os.PathLike[str]) -> list[np.ndarray]:
    """CSV with header ``query,references``: per query index its correct reference indices (space-separated).
    Returns a list indexed by query of int arrays."""
    try:
        with open(path, newline="") as f:
            rows = list(csv.reader(f))
    except OSError as e:
        raise VprError(f"{path}: cannot read ground truth ({e.strerror})") from None
    out: dict[int, np.ndarray] = {}
    for n, row in enumerate(rows[1:], start=2):
        try:
            out[int(row[0])] = np.array([int(v) for v in row[1].split()], dtype=np.int64)
        except (IndexError, ValueError):
            raise VprError(f"{path}: line {n}: expected 'query,ref ref ...'") from None
    if sorted(out) != list(range(len(out))):
        raise VprError(f"{path}: query indices must run 0..{len(out) - 1} without gaps")
    return [out[i] for i in range(len(out))]


def window_centres(truth: list[np.ndarray], margin: int, n_refs: int) -> np.ndarray:
    """The true reference per query when each ground-truth set is that reference +-``margin``, clipped to
    [0, n_refs): recovered from the side of the window that was not clipped. (Q,) int."""
    centres = np.empty(len(truth), np.int64)
    for q, refs in enumerate(truth):
        lo, hi = int(refs.min()), int(refs.max())
        if lo == 0 and hi < n_refs - 1:
            centres[q] = hi - margin
        elif hi == n_refs - 1 and lo > 0:
            centres[q] = lo + margin
        else:
            centres[q] = (lo + hi) // 2
    return centres


def fraction_within(pred: np.ndarray, truth: np.ndarray, tolerance: int) -> float:
    """Share of queries whose predicted reference is within ``tolerance`` frames of the true one."""
    return float(np.mean(np.abs(np.asarray(pred) - np.asarray(truth)) <= tolerance))


def fraction_in_sets(pred: np.ndarray, truth: list[np.ndarray]) -> float:
    """Share of queries whose predicted reference is one of its listed correct references."""
    return float(np.mean([p in t for p, t in zip(pred, truth)]))
