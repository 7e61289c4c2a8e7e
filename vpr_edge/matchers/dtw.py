"""Offline DTW over a whole query sequence, with backtracking.

Two step patterns over ``sim`` (Q, R):

* classic (fixed ends, the thesis): the path runs from (0, 0) to (Q-1, R-1) by steps (i-1, j) (vehicle
  stopped), (i, j-1) (skipping references) and (i-1, j-1). Each row is one prefix-sum scan:
  A[i, j] = best over k <= j of (M[k] + sum of step terms k..j), no Python loop over references.
* open ends (subsequence DTW that follows speed changes): the path may start and end at any reference and
  each query frame advances 0..``max_step`` references (steps (i-1, j-k)), so every path has exactly one cell
  per query frame: its sum is comparable whatever its slope, and a vehicle at 3 places per frame is followed
  as well as one at 1.

Variants: ``distance`` (minimise summed 1 - cos, the default) or ``similarity`` (maximise summed cos, the
thesis). With the classic pattern the similarity form rewards extra steps (its path drifts along runs);
the distance form charges them.

Per cell, the value of the best complete path through it is A + B - term (B: the same recursion run
backwards); it ranks the references of each row (recall@K) and gives each frame a margin score: how much
worse the best path avoiding the matched reference's neighbourhood (+-``rival_window``) is.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from vpr_edge.matchers.base import Result, lead_with, top_k

Variant = Literal["similarity", "distance"]
VARIANTS: tuple[str, ...] = ("distance", "similarity")


def _terms(sim: np.ndarray, variant: str) -> tuple[np.ndarray, np.ufunc]:
    """Per-cell step term and the accumulate ufunc: (s, maximum) for 'similarity', (1-s, minimum) else."""
    if variant == "similarity":
        return sim.astype(np.float64), np.maximum
    if variant == "distance":
        return 1.0 - sim.astype(np.float64), np.minimum
    raise ValueError(f"unknown DTW variant {variant!r}; choose from {VARIANTS}")


def row_scan(terms: np.ndarray, entry: np.ndarray, better: np.ufunc) -> tuple[np.ndarray, np.ndarray]:
    """Solve A[j] = terms[j] + better(entry[j], A[j-1]) for a whole row.

    Returns (A, k) where k[j] is the column at which the best path entered the row (then moved right).
    """
    p = np.cumsum(terms)
    shifted = np.concatenate(([0.0], p[:-1]))
    v = entry - shifted
    run = better.accumulate(v)
    k = np.maximum.accumulate(np.where(v == run, np.arange(len(v)), 0))
    return p + run, k


def _classic(terms: np.ndarray, better: np.ufunc, open_start: bool) -> np.ndarray:
    q, r = terms.shape
    acc = np.empty((q, r), np.float64)
    bad = -np.inf if better is np.maximum else np.inf
    entry = np.zeros(r) if open_start else np.full(r, bad)
    entry[0] = 0.0
    acc[0] = row_scan(terms[0], entry, better)[0]
    for i in range(1, q):
        prev = acc[i - 1]
        entry = prev.copy()
        entry[1:] = better(prev[1:], prev[:-1])
        acc[i] = row_scan(terms[i], entry, better)[0]
    return acc


def _jumps(terms: np.ndarray, better: np.ufunc, max_step: int) -> tuple[np.ndarray, np.ndarray]:
    """Open-ends pattern: A[i, j] = terms[i, j] + best over k in 0..max_step of A[i-1, j-k]; A[0] = terms[0].
    Returns (A, step) with step[i, j] the chosen k (int8)."""
    q, r = terms.shape
    bad = -np.inf if better is np.maximum else np.inf
    acc = np.empty((q, r), np.float64)
    step = np.zeros((q, r), np.int8)
    acc[0] = terms[0]
    padded = np.full(r + max_step, bad)
    for i in range(1, q):
        padded[max_step:] = acc[i - 1]
        cands = np.stack([padded[max_step - k: max_step - k + r] for k in range(max_step + 1)])
        pick = (np.argmax if better is np.maximum else np.argmin)(cands, axis=0)
        step[i] = pick
        acc[i] = terms[i] + cands[pick, np.arange(r)]
    return acc, step


def dtw_accumulate(sim: np.ndarray, *, variant: Variant, open_ends: bool, max_step: int) -> np.ndarray:
    """Accumulated matrix A (Q, R): classic from (0, 0), or with ``open_ends`` the jump pattern from any
    (0, j) with 0..``max_step`` references per query frame."""
    terms, better = _terms(np.asarray(sim), variant)
    if open_ends:
        return _jumps(terms, better, max_step)[0]
    return _classic(terms, better, False)


@dataclass(frozen=True)
class Alignment:
    """Offline DTW result: the path (P, 2) of (query, reference) cells in order; per query frame the matched
    reference (the most similar cell of that row on the path) and its similarity; the path's accumulated
    value (summed similarity or summed distance)."""

    path: np.ndarray
    matches: np.ndarray
    scores: np.ndarray
    total: float


def _backtrack_classic(acc: np.ndarray, pick) -> list[tuple[int, int]]:
    i, j = acc.shape[0] - 1, acc.shape[1] - 1
    path = [(i, j)]
    while i > 0 or j > 0:
        if i == 0:
            j -= 1
        elif j == 0:
            i -= 1
        else:
            k = int(pick([acc[i - 1, j - 1], acc[i - 1, j], acc[i, j - 1]]))
            i, j = ((i - 1, j - 1), (i - 1, j), (i, j - 1))[k]
        path.append((i, j))
    return path[::-1]


def dtw_align(sim: np.ndarray, *, variant: Variant, open_ends: bool, max_step: int) -> Alignment:
    """Align query and reference sequences by DTW over ``sim`` (Q, R) and backtrack the best path.

    Without ``open_ends`` the path runs from (0, 0) to (Q-1, R-1): both sequences cover the same route (ties in
    backtracking prefer the diagonal, then the vertical, then the horizontal step). With ``open_ends`` it
    may start and end at any reference and advances 0..``max_step`` references per query frame.
    """
    sim = np.asarray(sim)
    if sim.ndim != 2 or 0 in sim.shape:
        raise ValueError(f"similarity matrix must be 2-D and non-empty, got shape {sim.shape}")
    terms, better = _terms(sim, variant)
    pick = np.argmax if variant == "similarity" else np.argmin
    if open_ends:
        acc, step = _jumps(terms, better, max_step)
        j = int(pick(acc[-1]))
        cols = np.empty(sim.shape[0], np.int64)
        for i in range(sim.shape[0] - 1, -1, -1):
            cols[i] = j
            j -= int(step[i, j])
        cells = np.stack([np.arange(sim.shape[0]), cols], axis=1)
    else:
        acc = _classic(terms, better, False)
        cells = np.array(_backtrack_classic(acc, pick), dtype=np.int64)
    vals = sim[cells[:, 0], cells[:, 1]]
    # Best cell per query row: sort by (row, -similarity) and keep the first of each row.
    order = np.lexsort((-vals, cells[:, 0]))
    first = np.concatenate(([True], np.diff(cells[order, 0]) > 0))
    chosen = order[first]
    return Alignment(cells, cells[chosen, 1], vals[chosen], float(acc[cells[-1, 0], cells[-1, 1]]))


def through_values(sim: np.ndarray, *, variant: Variant, open_ends: bool, max_step: int) -> np.ndarray:
    """(Q, R): the value of the best complete path through each cell (forward + backward - the cell)."""
    terms, better = _terms(np.asarray(sim), variant)
    if open_ends:
        fwd = _jumps(terms, better, max_step)[0]
        bwd = _jumps(terms[::-1, ::-1], better, max_step)[0][::-1, ::-1]
    else:
        fwd = _classic(terms, better, False)
        bwd = _classic(terms[::-1, ::-1], better, False)[::-1, ::-1]
    return fwd + bwd - terms


def remove_hubs(sim: np.ndarray) -> np.ndarray:
    """(Q, R) -> each row z-scored over the references, then each reference's mean over the queries
    subtracted. A hub (a reference alike to every query: fog, a plain wall) would otherwise win any path
    that may stand still: on nordland-dev's pixels, reference 0's mean similarity to all queries (-0.806)
    beats the true matches' mean (-0.885), and open-ends DTW parked on it for the whole stream."""
    sim = np.asarray(sim, np.float64)
    z = (sim - sim.mean(axis=1, keepdims=True)) / np.maximum(sim.std(axis=1, keepdims=True), 1e-12)
    return z - z.mean(axis=0, keepdims=True)


def dtw_match(sim: np.ndarray, k: int = 10, *, variant: Variant, open_ends: bool, max_step: int, rival_window: int,
              hubs: bool) -> Result:
    """Registry entry (its parameters and their defaults: ``params.DTW``): the DTW path's reference per frame,
    the margin of the best path through it over the best path avoiding +-``rival_window`` references around it,
    and references ranked by through-value. ``hubs``: run on ``remove_hubs(sim)`` (offline, so the column means
    see the whole query sequence)."""
    sim = remove_hubs(sim) if hubs else np.asarray(sim)
    refs = dtw_align(sim, variant=variant, open_ends=open_ends, max_step=max_step).matches
    pref = through_values(sim, variant=variant, open_ends=open_ends, max_step=max_step)
    if variant == "distance":
        pref = -pref
    q, r = sim.shape
    own = pref[np.arange(q), refs]
    far = np.abs(np.arange(r)[None, :] - refs[:, None]) > rival_window
    rival = np.where(far, pref, -np.inf).max(axis=1)
    scores = np.where(np.isfinite(rival), own - rival, own - pref.min(axis=1))
    return Result(refs.astype(np.int64), scores.astype(np.float64), lead_with(refs, top_k(pref, k)))
