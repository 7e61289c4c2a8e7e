"""The ``stream-rules`` matcher's trajectory state and its recursion: H, the score of the best recent trajectory
ending at each (speed, position on the 1/``grid`` reference grid), and one frame of

    H_t(v, p) = max(0, decay * max_v' [H_{t-1}(v', p - v) - turn * |v - v'| * grid] + z_t(p) - bias)

given the frame's z_t - bias (``road``'s module docstring says what each term is for; ``RoadMatcher`` builds
on ``TrajectoryState`` and hands it that). The max over speeds with the speed penalty is a distance transform
(two passes over the speeds); a drive's start takes its predecessors from the junctions into it
(``route.RouteGraph``). The state is held over the whole route (preallocated buffers, reused every frame) or
compact over the windows a local or index search keeps, so that on a large map it costs memory for those
windows, not for every place.
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

from vpr_edge.matchers.route import Intervals, RouteGraph


def per_reference(state: np.ndarray, grid: int) -> np.ndarray:
    """The best trajectory ending at each reference: ``state`` (speeds, n * grid), its columns ``grid`` cells
    of each of n references in turn -> (n,), the highest over a reference's speeds and cells. Strided maxima,
    not ``reshape(n, grid).max(axis=1)``, whose length-``grid`` reduction costs about 30x as much per place."""
    cols = state.max(axis=0)
    out = cols[0::grid].copy()
    for k in range(1, grid):
        np.maximum(out, cols[k::grid], out=out)
    return out


class TrajectoryState:
    """The state H over (speed, position) of ``n_refs`` references on ``graph`` (``n_speeds`` speeds 0,
    1/``grid``, ... references per frame) and its recursion (``decay``, ``turn``; module docstring), held whole
    or compact over the windows searched."""

    def __init__(self, n_refs: int, grid: int, n_speeds: int, decay: float, turn: float, graph: RouteGraph) -> None:
        self.n_refs, self.grid, self.n_speeds, self.decay, self.turn = n_refs, grid, n_speeds, decay, turn
        self.graph = graph
        # trajectories across drives: state entries whose predecessor in map order is another drive's (cut),
        # and what the junctions carry from their sources' ends into their targets (fed)
        self._cut = self.graph.cuts(grid, self.n_speeds)
        self._feeds()
        self._joins = bool(len(self._cut[1]) or self._src_cols is not None)
        # the state H, held where it may be non-zero: over the whole route (``_full``, (speeds, positions); a
        # frame that searches everything) or compact over the intervals a local or index search keeps
        # (``_kept``; ``_cols``, their state columns; ``_vals``, (speeds, columns)), so that on a large map
        # searched around candidates it costs memory for the candidates' neighbourhoods, not for every place.
        # float32: the per-frame passes over (speeds x positions) are memory-bound; halving the bytes halved
        # the time at 100,000 references (python -m vpr_edge_bench bench-matcher)
        self._full: np.ndarray | None = None   # made at the first whole-route frame, kept (with its buffers)
        self._kept: Intervals | None = []      # None: the state is ``_full``
        self._cols = np.zeros(0, np.int64)
        self._vals = np.zeros((self.n_speeds, 0), np.float32)

    @property
    def h(self) -> np.ndarray:
        """The state H over every position, (speeds, n_refs * grid) float32 (zero where nothing is held; a copy
        unless the state is held whole)."""
        if self._kept is None:
            return self._full
        out = np.zeros((self.n_speeds, self.n_refs * self.grid), np.float32)
        out[:, self._cols] = self._vals
        return out

    def _take(self, cols: np.ndarray) -> np.ndarray:
        """The state at state columns ``cols`` (int array), (speeds, len(cols)); 0 where nothing is held."""
        if self._kept is None:
            return self._full[:, cols]
        out = np.zeros((self.n_speeds, len(cols)), np.float32)
        if len(self._cols) and len(cols):
            i = np.minimum(np.searchsorted(self._cols, cols), len(self._cols) - 1)
            ok = self._cols[i] == cols
            out[:, ok] = self._vals[:, i[ok]]
        return out

    def _hold(self, win: Intervals, cols: np.ndarray, vals: np.ndarray) -> None:
        """Hold the state compact: ``vals`` (speeds, len(cols)) at the state columns ``cols`` of ``win``."""
        self._kept, self._cols, self._vals = list(win), cols, np.ascontiguousarray(vals, np.float32)

    def _densify(self) -> None:
        """Hold the state over the whole route (``_full``, made once, with the whole-route pass's buffers)."""
        if self._kept is None:
            return
        if self._full is None:
            shape = (self.n_speeds, self.n_refs * self.grid)
            self._full = np.zeros(shape, np.float32)
            self._m, self._new = np.empty(shape, np.float32), np.empty(shape, np.float32)   # reused every frame
            self._zs = np.empty((2, shape[1]), np.float32)   # speed 0's share of z (and scratch)
            self._zbuf = np.empty(shape[1], np.float32)
        else:
            self._full.fill(0.0)
        self._full[:, self._cols] = self._vals
        self._kept = None

    def _state_cols(self, win: Intervals) -> np.ndarray:
        g = self.grid
        return np.concatenate([np.arange(lo * g, hi * g) for lo, hi in win]) if win else np.zeros(0, np.int64)

    def _advance(self, a: int, b: int, z: np.ndarray, gain: float, stop_decay: float,
                 fed: np.ndarray | None) -> None:
        """One frame of the recursion on the whole state's columns [a, b), ``z`` its frame's: the max over
        v' of H(v', p) - turn * |v - v'| (forward and backward passes over speeds), shifted v grid steps
        ahead, decayed, plus z (at speed 0: decayed by ``stop_decay``, plus ``gain`` of a positive z),
        floored at 0. Columns left of ``a`` feed it as predecessors, except across a drive's start, where
        the junctions into it do (``fed``: what each junction carries, ``_fed``)."""
        a0 = max(0, a - (self.n_speeds - 1))
        m, new, w = self._m[:, : b - a0], self._new[:, : b - a], b - a
        np.copyto(m, self._full[:, a0:b])
        self._speed_max(m)
        for v in range(self.n_speeds):   # a trajectory at speed v came from v grid steps behind
            k = a - v - a0
            if k >= 0:
                new[v] = m[v, k:k + w]
            else:                        # before the route's start: nothing
                new[v, :-k] = 0.0
                new[v, -k:] = m[v, : max(0, w + k)]   # nothing when the step is longer than the columns
        if self._joins:
            def locate(c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
                ok = (c >= a) & (c < b)
                return ok, c[ok] - a
            self._join(new, locate, fed)
        self._decay_and_add(new, z, gain, stop_decay, self._zs[:, :w])
        self._full[:, a:b] = new

    def _decay_and_add(self, new: np.ndarray, z: np.ndarray, gain: float, stop_decay: float,
                     scratch: np.ndarray) -> None:
        """In place on the shifted state ``new`` (speeds, columns): decayed (speed 0 by ``stop_decay``),
        floored at 0, plus the frame's ``z`` (speed 0: ``gain`` of a positive z), floored at 0 (``scratch``:
        (2, columns) float32)."""
        new[1:] *= self.decay
        new[0] *= stop_decay
        np.maximum(new, 0.0, out=new)
        zs, neg = scratch
        new[1:] += z
        np.maximum(z, 0.0, out=zs)
        zs *= gain
        np.minimum(z, 0.0, out=neg)
        zs += neg
        new[0] += zs
        np.maximum(new, 0.0, out=new)

    def _advance_many(self, wins: Intervals, z: np.ndarray, gain: float, stop_decay: float,
                      fed: np.ndarray | None) -> None:
        """``_advance`` over the windows of a local or index search (``z``: the frame's over their state
        columns, in order): their columns gathered into one compact array, each window after n_speeds - 1
        empty columns (nothing comes from outside the windows, where the state is 0), one pass of the
        recursion, the result held compact over the windows: a fixed number of array operations whatever the
        number of windows, memory for the windows only."""
        g, pad = self.grid, self.n_speeds - 1
        cols = np.concatenate([np.r_[np.full(pad, -1, np.int64), np.arange(lo * g, hi * g)] for lo, hi in wins])
        real = cols >= 0
        at, pos = cols[real], np.flatnonzero(real)
        m = np.zeros((self.n_speeds, len(cols)), np.float32)
        m[:, pos] = self._take(at)
        self._speed_max(m)
        new = np.zeros_like(m)
        new[0] = m[0]
        for v in range(1, self.n_speeds):   # a trajectory at speed v came from v grid steps behind
            new[v, v:] = m[v, :-v]
        if self._joins:
            def locate(c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
                i = np.minimum(np.searchsorted(at, c), len(at) - 1)
                ok = at[i] == c
                return ok, pos[i[ok]]
            self._join(new, locate, fed)
        zp = np.zeros(len(cols), np.float32)
        zp[pos] = z
        self._decay_and_add(new, zp, gain, stop_decay, np.empty((2, len(cols)), np.float32))
        self._hold(wins, at, new[:, pos])

    def _speed_max(self, m: np.ndarray) -> None:
        """In place over (speeds, columns): each entry the max over speeds v' of itself - turn * |v - v'|."""
        for v in range(1, self.n_speeds):
            np.maximum(m[v], m[v - 1] - self.turn, out=m[v])
        for v in range(self.n_speeds - 2, -1, -1):
            np.maximum(m[v], m[v + 1] - self.turn, out=m[v])

    def _feeds(self) -> None:
        """Precompute what ``_fed`` gathers and ``_join`` scatters: the junctions' source columns grouped by
        (junction, k) (``_src_cols``, ``_src_groups``; None: no junction) and the target entries (speed, column,
        group), sorted by column."""
        (sj, sk, sc), (tj, tv, tk, tc) = self.graph.feeds(self.grid, self.n_speeds)
        self._src_cols: np.ndarray | None = None
        self._tgt = (np.zeros(0, np.int64),) * 3
        if not len(sc):
            return
        gid = sj * self.n_speeds + sk
        order = np.argsort(gid, kind="stable")
        self._src_cols, g = sc[order], gid[order]
        speeds = np.arange(self.n_speeds)
        self._turns = (self.turn * np.abs(speeds[:, None] - speeds[None, :])).astype(np.float32)   # (v, v')
        self._src_groups = np.flatnonzero(np.r_[True, g[1:] != g[:-1]])
        row_of = np.full(len(self.graph.junctions) * self.n_speeds, -1, np.int64)
        row_of[g[self._src_groups]] = np.arange(len(self._src_groups))
        row = row_of[tj * self.n_speeds + tk]
        keep = row >= 0          # a (junction, k) with no source column (a drive shorter than the speeds reach)
        self._tgt = (tv[keep], tc[keep], row[keep])

    def _fed(self) -> np.ndarray | None:
        """What the junctions carry into the next frame, from the state as it is: (speeds, groups), per
        (junction, k) group the best speed-penalised state k columns back from the junction's end over its
        sources (None: a map without junctions)."""
        if self._src_cols is None:
            return None
        hs = (self._take(self._src_cols)[None] - self._turns[:, :, None]).max(axis=1)   # few columns: at once
        return np.maximum.reduceat(hs, self._src_groups, axis=1)

    def _join(self, new: np.ndarray, locate: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
              fed: np.ndarray | None) -> None:
        """The shifted state ``new``: predecessors across a drive's start dropped, those the junctions carry
        (``fed``) taken in. ``locate(columns)``: which of these state columns ``new`` holds (a mask) and where
        (their positions in it)."""
        cv, cc = self._cut
        ok, where = locate(cc)
        new[cv[ok], where] = 0.0
        if fed is None:
            return
        tv, tc, row = self._tgt
        ok, where = locate(tc)
        if ok.any():   # entries reaching one (speed, column) from several junctions: the best of them
            v = tv[ok]
            np.maximum.at(new, (v, where), fed[v, row[ok]])

    def ranking(self) -> np.ndarray:
        """Best trajectory score ending at each reference (R,) (0 where nothing is held)."""
        if self._kept is None:
            return per_reference(self._full, self.grid)
        out = np.zeros(self.n_refs, np.float32)
        out[self._cols[::self.grid] // self.grid] = per_reference(self._vals, self.grid)
        return out
