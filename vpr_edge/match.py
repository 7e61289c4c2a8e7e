"""Sequence matching: cosine similarity, offline DTW with backtracking, best single match, streaming DTW.

Conventions: ``sim`` is a (Q, R) matrix, query frames by rows and reference frames by columns; a DTW path
moves from (0, 0) to (Q-1, R-1) by steps (i-1, j) (vehicle stopped), (i, j-1) (skipping references) and
(i-1, j-1) (moving at the reference's pace). Each DTW row is computed in O(R) NumPy work with a prefix-sum
scan: A[i, j] = best over k <= j of (M[k] + sum of step terms k..j), so there is no Python loop over
references.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

Variant = Literal["similarity", "distance"]
VARIANTS: tuple[str, ...] = ("similarity", "distance")


def cosine_similarity(queries: np.ndarray, refs: np.ndarray) -> np.ndarray:
    """(Q, D) and (R, D) -> (Q, R) cosine similarities in [-1, 1] (rows of zeros give 0)."""
    q = queries / np.maximum(np.linalg.norm(queries, axis=1, keepdims=True), 1e-12)
    r = refs / np.maximum(np.linalg.norm(refs, axis=1, keepdims=True), 1e-12)
    return q @ r.T


def best_match(sim: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Baseline without sequence information: per query row the most similar reference and its similarity."""
    idx = np.argmax(sim, axis=1)
    return idx, sim[np.arange(len(sim)), idx]


def _terms(sim: np.ndarray, variant: str) -> tuple[np.ndarray, np.ufunc]:
    """Per-cell step term and the accumulate ufunc: (s, maximum) for 'similarity', (1-s, minimum) else."""
    if variant == "similarity":
        return sim.astype(np.float64), np.maximum
    if variant == "distance":
        return 1.0 - sim.astype(np.float64), np.minimum
    raise ValueError(f"unknown DTW variant {variant!r}; choose from {VARIANTS}")


def _row_scan(terms: np.ndarray, entry: np.ndarray, better: np.ufunc) -> tuple[np.ndarray, np.ndarray]:
    """Solve A[j] = terms[j] + better(entry[j], A[j-1]) for a whole row.

    Returns (A, k) where k[j] is the column at which the best path entered the row (then moved right).
    """
    p = np.cumsum(terms)
    shifted = np.concatenate(([0.0], p[:-1]))
    v = entry - shifted
    run = better.accumulate(v)
    k = np.maximum.accumulate(np.where(v == run, np.arange(len(v)), 0))
    return p + run, k


def dtw_accumulate(sim: np.ndarray, variant: Variant = "similarity", open_ends: bool = False) -> np.ndarray:
    """Accumulated matrix A (Q, R) of DTW from (0, 0), or from any (0, j) with ``open_ends``: the thesis
    variant maximises summed similarity, the distance variant minimises summed 1 - similarity."""
    terms, better = _terms(sim, variant)
    q, r = terms.shape
    acc = np.empty((q, r), np.float64)
    bad = -np.inf if variant == "similarity" else np.inf
    entry = np.zeros(r) if open_ends else np.full(r, bad)
    entry[0] = 0.0
    acc[0] = _row_scan(terms[0], entry, better)[0]
    for i in range(1, q):
        prev = acc[i - 1]
        entry = prev.copy()
        entry[1:] = better(prev[1:], prev[:-1])
        acc[i] = _row_scan(terms[i], entry, better)[0]
    return acc


@dataclass(frozen=True)
class Alignment:
    """Offline DTW result: the path (P, 2) of (query, reference) cells in order;
    per query frame the matched reference (the most similar cell of that row on the path) and its
    similarity; and the path's accumulated value (summed similarity or summed distance)."""

    path: np.ndarray
    matches: np.ndarray
    scores: np.ndarray
    total: float


def dtw_align(sim: np.ndarray, variant: Variant = "similarity", open_ends: bool = False) -> Alignment:
    """Align query and reference sequences by DTW over ``sim`` (Q, R) and backtrack the best path.

    By default the path runs from (0, 0) to (Q-1, R-1): both sequences cover the same route. With
    ``open_ends`` (subsequence DTW) it may start and end at any reference, for a query that covers part of
    the mapped route. Ties in backtracking prefer the diagonal, then the vertical, then the horizontal step.
    """
    sim = np.asarray(sim)
    if sim.ndim != 2 or 0 in sim.shape:
        raise ValueError(f"similarity matrix must be 2-D and non-empty, got shape {sim.shape}")
    acc = dtw_accumulate(sim, variant, open_ends)
    pick = np.argmax if variant == "similarity" else np.argmin
    i, j = sim.shape[0] - 1, (int(pick(acc[-1])) if open_ends else sim.shape[1] - 1)
    path = [(i, j)]
    while i > 0 or j > 0:
        if i == 0:
            if open_ends and pick([0.0, acc[0, j - 1]]) == 0:
                break                      # the path started here rather than coming from the left
            j -= 1
        elif j == 0:
            i -= 1
        else:
            step = int(pick([acc[i - 1, j - 1], acc[i - 1, j], acc[i, j - 1]]))
            i, j = ((i - 1, j - 1), (i - 1, j), (i, j - 1))[step]
        path.append((i, j))
    cells = np.array(path[::-1], dtype=np.int64)
    vals = sim[cells[:, 0], cells[:, 1]]
    # Best cell per query row: sort by (row, -similarity) and keep the first of each row.
    order = np.lexsort((-vals, cells[:, 0]))
    first = np.concatenate(([True], np.diff(cells[order, 0]) > 0))
    chosen = order[first]
    return Alignment(cells, cells[chosen, 1], vals[chosen], float(acc[cells[-1, 0], cells[-1, 1]]))


class StreamingDTW:
    """DTW over an unbounded stream with O(R) work and O(R) memory per frame.

    The distance form is used (step term 1 - cos): every step costs, so paths cannot run ahead along the
    references for free, which the similarity form would reward once the path's end is open. Each cell
    holds the best path cost ending there, with the previous frame's cost discounted by ``decay`` (0 < decay
    < 1; memory of about 1 / (1 - decay) frames), so evidence from before the vehicle left the mapped route
    fades and a path re-forms wherever it re-enters. The path may begin at any reference.

    ``update`` returns the reference at the end of the cheapest path and a score: the decayed mean cosine
    similarity along that path (1 = perfect, lower = less confident).
    """

    def __init__(self, n_refs: int, decay: float = 0.9) -> None:
        if n_refs < 1:
            raise ValueError("need at least one reference")
        if not 0.0 < decay < 1.0:
            raise ValueError(f"decay must be in (0, 1), got {decay}")
        self.n_refs = n_refs
        self.decay = decay
        self.cost = np.zeros(n_refs, np.float64)      # decayed path cost ending at each reference
        self.weight = np.zeros(n_refs, np.float64)    # decayed number of steps on that path
        self.frames = 0

    def update(self, sim_row: np.ndarray) -> tuple[int, float]:
        """Advance by one query frame given its similarity to every reference (R,); return (ref, score)."""
        s = np.asarray(sim_row, np.float64)
        if s.shape != (self.n_refs,):
            raise ValueError(f"similarity row must have shape ({self.n_refs},), got {s.shape}")
        prev_c, prev_w = self.decay * self.cost, self.decay * self.weight
        entry_c, entry_w = prev_c.copy(), prev_w.copy()
        if self.frames:
            diag = prev_c[:-1] < entry_c[1:]
            entry_c[1:] = np.where(diag, prev_c[:-1], entry_c[1:])
            entry_w[1:] = np.where(diag, prev_w[:-1], entry_w[1:])
        cost, k = _row_scan(1.0 - s, entry_c, np.minimum)
        self.weight = entry_w[k] + (np.arange(self.n_refs) - k + 1)
        self.cost = cost
        self.frames += 1
        best = int(np.argmin(cost))
        return best, float(1.0 - cost[best] / self.weight[best])

    def reset(self) -> None:
        """Forget the stream (e.g. after a long gap)."""
        self.cost[:] = 0.0
        self.weight[:] = 0.0
        self.frames = 0
