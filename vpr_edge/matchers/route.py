"""The route a streaming matcher follows: its places as sequences (a map's drives, one after another in map
order) and the junctions where one sequence continues into another.

A trajectory moves forward within its sequence; at a sequence's start its predecessors are not the places
before it in map order (the end of another drive) but only the sources of the junctions into it, if any;
any place that is a junction's target may also be reached from that junction's sources. ``near`` is what
"close to a place" means on such a route (a local search's window, a rival's distance): within a number
of places along the sequence and, across a junction within reach, along the next one.
"""
from __future__ import annotations

from bisect import bisect_right
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

Intervals = list[tuple[int, int]]   # sorted, disjoint [lo, hi) ranges of places


@dataclass(frozen=True)
class RouteGraph:
    """``n_refs`` places in sequences starting at ``starts`` ((S,) int, increasing, ``starts[0] == 0``), and
    ``junctions``: (sources, targets) place arrays, each target may follow any source."""

    n_refs: int
    starts: np.ndarray = field(default_factory=lambda: np.zeros(1, np.int64))
    junctions: tuple[tuple[np.ndarray, np.ndarray], ...] = ()

    def __post_init__(self) -> None:
        starts = np.asarray(self.starts, np.int64)
        if starts.ndim != 1 or not len(starts) or starts[0] != 0 or (np.diff(starts) <= 0).any() or \
                starts[-1] >= self.n_refs:
            raise ValueError(f"sequence starts must rise from 0 within the {self.n_refs} places, got {starts}")
        object.__setattr__(self, "starts", starts)
        fixed = []
        for sources, targets in self.junctions:
            s, t = np.unique(np.asarray(sources, np.int64)), np.unique(np.asarray(targets, np.int64))
            if not (len(s) and len(t)) or min(s.min(), t.min()) < 0 or max(s.max(), t.max()) >= self.n_refs:
                raise ValueError(f"a junction's places must lie in 0..{self.n_refs - 1}")
            fixed.append((s, t))
        object.__setattr__(self, "junctions", tuple(fixed))
        object.__setattr__(self, "_firsts", [int(v) for v in starts])                       # for bisect
        object.__setattr__(self, "_lasts", [int(v) - 1 for v in starts[1:]] + [self.n_refs - 1])

    @classmethod
    def line(cls, n_refs: int) -> "RouteGraph":
        """One sequence, no junctions: a map of one drive."""
        return cls(n_refs)

    @property
    def simple(self) -> bool:
        """One sequence and no junction (a map of one drive)."""
        return len(self.starts) == 1 and not self.junctions

    @property
    def ends(self) -> np.ndarray:
        """(S,) the last place of each sequence."""
        return np.array(self._lasts, np.int64)

    def bounds(self, ref: int) -> tuple[int, int]:
        """(first, last) place of ``ref``'s sequence."""
        k = bisect_right(self._firsts, ref) - 1
        return self._firsts[k], self._lasts[k]

    def near(self, ref: int, w: int, gap: int = 0) -> Intervals:
        """The places within ``w`` steps of place ``ref`` along the route: its sequence within ``w`` either
        side and, across each junction whose source (target) lies within ``w`` ahead of (behind) ``ref`` in
        its sequence, the rest of the ``w`` steps into the targets' (sources') sequences. Sorted, merged
        intervals (two less than ``gap`` places apart merged into one)."""
        first, last = self.bounds(ref)
        out = [(max(first, ref - w), min(last, ref + w) + 1)]
        for sources, targets in self.junctions:
            ahead = sources[(sources >= ref) & (sources <= min(last, ref + w))]
            if len(ahead):
                left = w - int(ahead[0] - ref) - 1
                out += [(int(t), min(self.bounds(int(t))[1], int(t) + left) + 1) for t in targets] if left >= 0 else []
            behind = targets[(targets <= ref) & (targets >= max(first, ref - w))]
            if len(behind):
                left = w - int(ref - behind[-1]) - 1
                out += [(max(self.bounds(int(s))[0], int(s) - left), int(s) + 1) for s in sources] if left >= 0 else []
        return merge(out, gap)

    def cuts(self, grid: int, n_speeds: int) -> tuple[np.ndarray, np.ndarray]:
        """The (speed, column) entries of the matcher's state, on a grid of ``grid`` columns a place with
        speeds 0..n_speeds-1 columns a frame, whose predecessor in map order lies before their sequence's
        start (in another drive): (v (E,), column (E,)) int arrays, sorted by column."""
        vs, cols = [], []
        for s, e in zip(self.starts[1:], self.ends[1:]):
            for i in range(min(n_speeds - 1, (e - s + 1) * grid)):
                for v in range(i + 1, n_speeds):
                    vs.append(v)
                    cols.append(int(s) * grid + i)
        return _sorted_by_column(np.array(vs, np.int64), np.array(cols, np.int64))

    def feeds(self, grid: int, n_speeds: int) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
        """What the junctions carry, on the matcher's grid. Sources: (junction, k, column) arrays: a state
        ``k`` columns back from a junction's end (k = 1: a source place's last column). Targets: (junction,
        v, k, column) arrays, sorted by column: the state at ``column`` and speed ``v`` whose predecessor lies
        ``k`` columns back behind the junction."""
        sj, sk, sc, tj, tv, tk, tc = ([] for _ in range(7))
        for j, (sources, targets) in enumerate(self.junctions):
            for s in sources:
                first = self.bounds(int(s))[0] * grid
                for k in range(1, n_speeds):
                    col = int(s) * grid + grid - k
                    if col >= first:
                        sj.append(j), sk.append(k), sc.append(col)
            for t in targets:
                end = (self.bounds(int(t))[1] + 1) * grid
                for v in range(1, n_speeds):
                    for i in range(v):
                        if int(t) * grid + i < end:
                            tj.append(j), tv.append(v), tk.append(v - i), tc.append(int(t) * grid + i)
        src = tuple(np.array(a, np.int64) for a in (sj, sk, sc))
        order = np.argsort(np.array(tc, np.int64), kind="stable")
        tgt = tuple(np.array(a, np.int64)[order] for a in (tj, tv, tk, tc))
        return src, tgt


def merge(intervals: Sequence[tuple[int, int]], gap: int = 0) -> Intervals:
    """[lo, hi) ranges -> sorted, disjoint ranges covering the same places (and the gaps of less than
    ``gap`` places between two of them)."""
    out: Intervals = []
    for lo, hi in sorted(i for i in intervals if i[1] > i[0]):
        if out and lo <= out[-1][1] + max(0, gap - 1):
            out[-1] = (out[-1][0], max(out[-1][1], hi))
        else:
            out.append((lo, hi))
    return out


def minus(a: Intervals, b: Intervals) -> Intervals:
    """The places of sorted, disjoint intervals ``a`` that are not in ``b`` (also sorted and disjoint)."""
    out: Intervals = []
    for lo, hi in a:
        at = lo
        for blo, bhi in b:
            if bhi <= at or blo >= hi:
                continue
            if blo > at:
                out.append((at, blo))
            at = max(at, bhi)
        if at < hi:
            out.append((at, hi))
    return out


def places(intervals: Intervals) -> np.ndarray:
    """Sorted, disjoint intervals -> their places, in order (int64)."""
    if len(intervals) == 1:
        return np.arange(*intervals[0])
    return np.concatenate([np.arange(lo, hi) for lo, hi in intervals]) if intervals else np.zeros(0, np.int64)


def max_outside(values: np.ndarray, refs: np.ndarray | None, intervals: Intervals) -> float:
    """The highest of ``values`` (one per place of ``refs``, sorted; None: places 0..len-1) whose place lies
    outside ``intervals``; 0 if there is none."""
    if refs is None:
        best, at = 0.0, 0
        for lo, hi in intervals:
            best = max(best, float(values[at:lo].max(initial=0.0)))
            at = hi
        return max(best, float(values[at:].max(initial=0.0)))
    return float(values[~inside(refs, intervals)].max(initial=0.0))


def inside(refs: np.ndarray, intervals: Intervals) -> np.ndarray:
    """Whether each place of ``refs`` (int array) lies in one of the sorted, disjoint ``intervals``: (n,) bool."""
    refs = np.asarray(refs, np.int64)
    if not intervals:
        return np.zeros(len(refs), bool)
    los = np.array([lo for lo, _ in intervals], np.int64)
    his = np.array([hi for _, hi in intervals], np.int64)
    k = np.searchsorted(los, refs, side="right") - 1
    return (k >= 0) & (refs < his[np.maximum(k, 0)])


def _sorted_by_column(v: np.ndarray, col: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    order = np.argsort(col, kind="stable")
    return v[order], col[order]
