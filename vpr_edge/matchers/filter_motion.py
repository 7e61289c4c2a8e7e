"""The stream filter's motion model (``bayes``, step 1): over the whole route (``Transitions``), or over a
window of places around its answer on a long route (``Window``), the rest of the on-map mass held as one
number spread evenly over its places (*elsewhere*); and what the motion cue says of the speed (``cue_weights``,
step 3).

Speeds are 0 (standing), a slow ``SLOW_SPEED`` (half a place a frame: a camera slower than the map's drive),
then one place a frame to ``vmax`` in steps of ``speed_step`` (0.5: 1, 1.5, 2, ..). A speed between whole
places moves the camera by whole places in a fixed cycle (1.5: one place, then two; ``phases``), each step of
the cycle a row of the state, so a trajectory at 1.5 is a line, not a random walk. A speed changes to the next
one up or down with probability ``speed_change`` each (standing and one place a frame are neighbours); the slow
speed is reached from standing or one place a frame with probability ``SLOW_CHANGE`` only: a stop that repeats
its view is read by the motion cue, and a slow speed held without need lets a trajectory linger by a look-alike
(docs/decisions.md).

On a route of more than ``4 * window`` places the filter reads only the places within ``window`` of a firm
answer (and a fixed probe sample for the row's median and spread), as ``stream-rules``' local search does; every
``check`` frames it reads the whole route for ``span`` frames, and it reads it whenever the answer is not
firm. ``Window`` moves the mass it holds one frame on with the same motion model as the whole-route
``Transitions``; what leaves the window joins *elsewhere*, what enters it comes from there. On a
window of every place it is ``Transitions`` exactly (tested).

Mass that comes onto the map (the stream's start, a return from off the map, a re-localisation, places newly
held from *elsewhere*) lands on every place alike and on the speeds as the motion model holds them in the long
run (``stationary``): the slow speed is as rare there as ``SLOW_CHANGE`` makes it anywhere else.
"""
from __future__ import annotations

import math
from fractions import Fraction

import numpy as np

from vpr_edge.matchers.constants import (CUE_FLOOR, CUE_MOVING_SD, CUE_STANDING, GO_BLIND, JOIN, MAX_PHASES,
                                         SLOW_CHANGE, SLOW_SPEED)
from vpr_edge.matchers.filter_config import FilterConfig
from vpr_edge.matchers.route import RouteGraph


def speed_values(vmax: int, step: float) -> np.ndarray:
    """The speeds followed, places a frame (U,): 0, ``SLOW_SPEED``, then 1 to ``vmax`` in steps of ``step``
    (none but 0 when ``vmax`` is 0)."""
    if vmax < 1:
        return np.zeros(1)
    return np.r_[0.0, SLOW_SPEED, 1.0 + step * np.arange(int(round((vmax - 1) / step)) + 1)]


def phases(speed: float) -> list[int]:
    """The whole places a camera at ``speed`` places a frame moves in each frame of its cycle (1.5: [1, 2];
    0.5: [0, 1]; 2: [2]); ValueError where the fraction is not a multiple of 1/n for n <= ``MAX_PHASES``."""
    frac = Fraction(speed).limit_denominator(MAX_PHASES)
    if abs(float(frac) - speed) > 1e-9:
        raise ValueError(f"a speed of {speed} places a frame has no cycle of at most {MAX_PHASES} frames")
    n = frac.denominator
    return [math.floor((j + 1) * frac) - math.floor(j * frac) for j in range(n)]


def speed_rows(speeds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The state's rows: one per frame of each speed's cycle (``phases``) -> (each row's speed index (V,),
    the whole places each row moves in a frame (V,))."""
    of = [i for i, s in enumerate(speeds) for _ in phases(float(s))]
    moves = [d for s in speeds for d in phases(float(s))]
    return np.array(of, np.int64), np.array(moves, np.int64)


def by_move(moves: np.ndarray) -> list[tuple[int, np.ndarray]]:
    """The rows grouped by the places they move: (places, the rows (int64)), by places, so the motion model
    shifts the mass once a distance, not once a row."""
    return [(int(d), np.flatnonzero(moves == d)) for d in np.unique(moves)]


def value_kernel(speeds: np.ndarray, change: float) -> np.ndarray:
    """(U, U) row-stochastic over ``speed_values``: to the next speed up or down with probability ``change``
    each (standing's next up is one place a frame; a change that would leave the range stays); into the slow
    speed from standing or one place a frame with ``SLOW_CHANGE``, out of it to either with ``change``. The
    order is ``speed_values``': standing, slow, then one place a frame and up."""
    n = len(speeds)
    k = np.zeros((n, n))
    if n == 1:
        k[0, 0] = 1.0
        return k
    moving = [0] + list(range(2, n))   # standing, then 1 .. vmax: the ladder of speeds
    for j, v in enumerate(moving):
        for w in (moving[max(j - 1, 0)], moving[min(j + 1, len(moving) - 1)]):
            k[v, w] += change
    for v in (0, 2):   # standing and one place a frame: into the slow speed
        k[v, 1] += SLOW_CHANGE
    k[1, 0] = k[1, 2] = change
    k[np.arange(n), np.arange(n)] += 1.0 - k.sum(axis=1)
    return k


def speed_kernel(speeds: np.ndarray, of: np.ndarray, change: float) -> np.ndarray:
    """(V, V) row-stochastic over the rows (``speed_rows``' ``of``): a speed kept moves on to the next step of
    its cycle; a change (``value_kernel``) lands on each step of the new speed's cycle alike."""
    k_val = value_kernel(speeds, change)
    n = len(of)
    k = np.zeros((n, n))
    first = {int(u): int(np.flatnonzero(of == u)[0]) for u in np.unique(of)}
    count = np.bincount(of)
    for r in range(n):
        u = int(of[r])
        nxt = r + 1 if r + 1 < n and of[r + 1] == u else first[u]
        k[r, nxt] += k_val[u, u]
        for w in np.flatnonzero(k_val[u]):
            if w != u:
                k[r, of == w] += k_val[u, w] / count[w]
    return k


def stationary(kernel: np.ndarray) -> np.ndarray:
    """A row-stochastic (V, V) kernel -> its long-run distribution over the rows (V,) (``p = p @ kernel``,
    summing to 1): how the speed rows share mass that has moved by the motion model for a long time."""
    n = len(kernel)
    a = np.vstack([kernel.T - np.eye(n), np.ones((1, n))])
    rhs = np.zeros(n + 1)
    rhs[-1] = 1.0
    p = np.linalg.lstsq(a, rhs, rcond=None)[0]
    p = np.maximum(p, 0.0)
    return p / p.sum()


def cue_weights(cue: float, as_motion: bool = False) -> tuple[float, float]:
    """A frame's motion cue (``motion.MotionCue``: 1 the same view again, 0 a typical moving step) -> the
    weights (moving, standing) of the moving speeds and of speed 0: the cue's density where the camera moves
    (normal about 0, sd ``CUE_MOVING_SD``) and where it stands (normal about ``CUE_STANDING``), the larger
    scaled to 1 and neither below ``CUE_FLOOR``. ``as_motion``: the map's drive stood here too, so the frame
    is read as motion (1, ``CUE_FLOOR``), as the map's references were."""
    if as_motion:
        return 1.0, CUE_FLOOR
    mean, sd = CUE_STANDING
    log_stand = -0.5 * ((cue - mean) / sd) ** 2 - math.log(sd)
    log_move = -0.5 * (cue / CUE_MOVING_SD) ** 2 - math.log(CUE_MOVING_SD)
    top = max(log_stand, log_move)
    return max(math.exp(log_move - top), CUE_FLOOR), max(math.exp(log_stand - top), CUE_FLOOR)


def blind(kernel: np.ndarray, one: int) -> np.ndarray:
    """A speed kernel (V, V) for frames with no motion cue: a stopped camera (row 0) also starts again at one
    place a frame (row ``one``) with probability ``GO_BLIND``. With a cue, each moving frame tells the filter it
    moves; without one, broad evidence (neighbouring places alike) could hold it at speed 0 while the camera
    drives on."""
    k = kernel.copy()
    k[0] *= 1.0 - GO_BLIND
    k[0, one] += GO_BLIND
    return k


def overruns(graph: RouteGraph, dmax: int) -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Where mass that moves past a drive's end lands: per whole step d (1..``dmax``), (sources, landings,
    shares) (n,) each: a place within d of a drive's end that is a junction's source moves on into each of
    that junction's targets alike, as far past the target as it overran the end (``near``'s continuation).
    Landings past their own drive's end are left out: that mass leaves the map."""
    ends = graph.ends
    into: dict[int, set[int]] = {}
    for sources, targets in graph.junctions:
        for e in np.intersect1d(sources, ends):
            into.setdefault(int(e), set()).update(int(t) for t in targets)
    out = {}
    for d in range(1, dmax + 1):
        src, dst, share = [], [], []
        for e, targets in sorted(into.items()):
            first = graph.bounds(e)[0]
            for p in range(max(first, e - d + 1), e + 1):
                k = p + d - e - 1   # places past the target
                for t in sorted(targets):
                    if t + k <= graph.bounds(t)[1]:
                        src.append(p), dst.append(t + k), share.append(1.0 / len(targets))
        out[d] = (np.array(src, np.int64), np.array(dst, np.int64), np.array(share))
    return out


def forks(graph: RouteGraph) -> list[tuple[np.ndarray, np.ndarray]]:
    """The junctions whose sources lie inside a drive (not at its end): the camera there may go on along its
    drive or turn into the targets (``JOIN``). A drive's end only continues (``overruns``)."""
    out = []
    for sources, targets in graph.junctions:
        inner = np.setdiff1d(sources, graph.ends)
        if len(inner):
            out.append((inner, targets))
    return out


class Transitions:
    """The motion model on a route graph: ``predict(b, off)`` moves the on-map mass ``b`` (V, R) and the
    off-map mass one frame on (``bayes`` module docstring, step 1)."""

    def __init__(self, graph: RouteGraph, config: FilterConfig) -> None:
        self.graph, self.config = graph, config
        self.speeds = speed_values(config.vmax, config.speed_step)
        self.of, self.moves = speed_rows(self.speeds)   # the state's rows: each speed's cycle
        self.n_speeds = len(self.of)
        self.shifts = by_move(self.moves)
        self.kernel = speed_kernel(self.speeds, self.of, config.speed_change)
        self.prior = stationary(self.kernel)   # (V,) how mass coming onto the map shares the speed rows
        one = np.flatnonzero(self.speeds == 1.0)
        self.blind_kernel = blind(self.kernel, int(np.flatnonzero(self.of == one[0])[0]) if len(one) else 0)
        later = [(int(s), int(e) + 1) for s, e in zip(graph.starts[1:], graph.ends[1:])]
        dmax = int(self.moves.max())
        self.cut = {d: np.concatenate([np.arange(s, min(s + d, e)) for s, e in later]).astype(np.int64)
                    if later else np.zeros(0, np.int64) for d in range(1, dmax + 1)}
        self.over = overruns(graph, dmax)   # past a drive's end, into the drives that follow it
        self.forks = forks(graph)

    def entry(self) -> np.ndarray:
        """Where mass coming onto the map lands: (V, R), every place alike, the speed rows by ``prior``
        (``stationary``), summing to 1."""
        return np.repeat(self.prior[:, None] / self.graph.n_refs, self.graph.n_refs, axis=1)

    def predict(self, b: np.ndarray, off: float, kernel: np.ndarray | None = None,
                hazard: float = 1.0) -> tuple[np.ndarray, float]:
        """(V, R) on-map mass and the off-map mass -> the same one frame on (sums kept); ``kernel``: the
        speeds' (None: ``kernel``); ``hazard``: the share of ``leave``, ``jump`` and ``enter`` that happens
        this frame (a standing camera's: ``bayes``, step 3)."""
        c = self.config
        leave, jump, enter = hazard * c.leave, hazard * c.jump, hazard * c.enter
        b = (self.kernel if kernel is None else kernel).T @ b
        r = b.shape[1]
        ran = 0.0
        moved = np.zeros_like(b)
        for d, rows in self.shifts:   # the rows that move d places
            if d == 0:
                moved[rows] = b[rows]
                continue
            if d >= r:
                ran += float(b[rows].sum())
                continue
            moved[rows, d:] = b[rows, :-d]
            ran += float(b[rows, r - d:].sum())
            cc = self.cut[d]
            if len(cc):   # came from another drive's end: off the map instead
                ran += float(moved[np.ix_(rows, cc)].sum())
                moved[np.ix_(rows, cc)] = 0.0
            src, dst, share = self.over[d]
            if len(src):   # ... or on into the drives that follow that end
                went = b[np.ix_(rows, src)] * share
                np.add.at(moved, (rows[:, None], dst[None, :]), went)
                ran -= float(went.sum())
        for sources, targets in self.forks:
            share = moved[:, sources].sum(axis=1) * JOIN
            moved[:, sources] *= 1.0 - JOIN
            moved[:, targets] += (share / len(targets))[:, None]
        on = float(moved.sum())
        out = moved * (1.0 - leave - jump)
        out += (jump * on + enter * off) * self.prior[:, None] / r   # as ``entry``
        return out, off * (1.0 - enter) + leave * on + ran


class Window:
    """The places ``cols`` (sorted int64 (W,)) of ``graph`` held at rows that move ``moves`` (V,) whole places a
    frame: for each row and column, where its mass comes from (``src``: a flat index into the (V, W) mass, or
    past its end: ``gone`` for a predecessor in another drive (no mass), ``gone + 1 + row`` for one outside the
    window (*elsewhere*'s density at that row)), and whether moving on leaves the map (``exit_off``: past its
    drive's end) or the window (``exit_else``); ``prior`` (V,): how *elsewhere* and mass coming onto the map
    share the rows (``Transitions.prior``); ``over`` and ``forks``: the route's (``overruns``, ``forks``; None:
    made here).
    Mass that overruns a held drive end lands on the held places that follow it (``cont``), or joins
    elsewhere; a drive start's predecessor outside the window brings none."""

    def __init__(self, graph: RouteGraph, cols: np.ndarray, moves: np.ndarray, prior: np.ndarray,
                 over: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None,
                 fork_list: list[tuple[np.ndarray, np.ndarray]] | None = None) -> None:
        self.graph, self.cols, self.moves = graph, np.asarray(cols, np.int64), np.asarray(moves, np.int64)
        self.prior = np.asarray(prior, np.float64)
        over = overruns(graph, int(self.moves.max())) if over is None else over
        fork_list = forks(graph) if fork_list is None else fork_list
        starts = np.asarray(graph.starts, np.int64)
        k = np.searchsorted(starts, self.cols, side="right") - 1
        first, last = starts[k], graph.ends[k]
        d = self.moves[:, None]
        before, after = self.cols[None, :] - d, self.cols[None, :] + d
        pos, inside = self.positions(before)
        n_v, w = len(self.moves), len(self.cols)
        self.gone = n_v * w
        flat = np.arange(n_v)[:, None] * w + pos
        self.src = np.where(before < first, self.gone, np.where(inside, flat, self.gone + 1 + np.arange(n_v)[:, None]))
        self.n_from_else = (self.src > self.gone).sum(axis=1)   # (V,) columns of each row fed from elsewhere
        self.exit_off = after > last
        self.exit_else = ~self.exit_off & ~self.positions(after)[1]
        self.joins = [(self.positions(s)[0][self.positions(s)[1]], self.positions(t)[0][self.positions(t)[1]],
                       len(t)) for s, t in fork_list]
        self.cont = []   # (rows, source columns, landing columns (-1: elsewhere), shares)
        for dd in np.unique(self.moves[self.moves > 0]):
            src, dst, share = over[int(dd)]
            if not len(src):
                continue
            s_pos, s_in = self.positions(src)
            if not s_in.any():
                continue
            d_pos, d_in = self.positions(dst[s_in])
            self.cont.append((np.flatnonzero(self.moves == dd), s_pos[s_in], np.where(d_in, d_pos, -1),
                              share[s_in]))

    def positions(self, places: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Places (any shape) -> (their columns, clipped; whether the window holds them)."""
        pos = np.clip(np.searchsorted(self.cols, places), 0, len(self.cols) - 1)
        return pos, self.cols[pos] == places

    def predict(self, b: np.ndarray, off: float, elsewhere: float, leave: float, jump: float, enter: float,
                kernel: np.ndarray) -> tuple[np.ndarray, float, float]:
        """(V, W) window mass, the off-map and elsewhere masses -> the same one frame on (sums kept)."""
        r, w = self.graph.n_refs, len(self.cols)
        density = elsewhere * self.prior / (r - w) if r > w else np.zeros(len(self.moves))   # (V,) a place
        b = kernel.T @ b
        moved = np.concatenate([b.ravel(), [0.0], density])[self.src]
        ran = float(b[self.exit_off].sum())
        elsewhere += float(b[self.exit_else].sum()) - float(density @ self.n_from_else)
        for rows, src, dst, share in self.cont:   # on past a drive's end into the drives that follow it
            went = b[np.ix_(rows, src)] * share
            held = dst >= 0
            np.add.at(moved, (rows[:, None], dst[None, held]), went[:, held])
            elsewhere += float(went[:, ~held].sum())
            ran -= float(went.sum())
        for sources, targets, n_targets in self.joins:
            share = moved[:, sources].sum(axis=1) * JOIN
            moved[:, sources] *= 1.0 - JOIN
            if len(targets):
                moved[:, targets] += (share / n_targets)[:, None]
            elsewhere += float(share.sum()) * (n_targets - len(targets)) / n_targets
        on = float(moved.sum()) + elsewhere
        spread = jump * on + enter * off
        out = moved * (1.0 - leave - jump) + spread * self.prior[:, None] / r
        elsewhere = elsewhere * (1.0 - leave - jump) + spread * (r - w) / r
        return out, off * (1.0 - enter) + leave * on + ran, max(elsewhere, 0.0)


def regather(b: np.ndarray, cols: np.ndarray, elsewhere: float, new: np.ndarray, n_refs: int,
             prior: np.ndarray) -> tuple[np.ndarray, float]:
    """Mass (V, W) held at places ``cols`` and ``elsewhere`` -> the same held at places ``new``: columns
    leaving join elsewhere, columns entering take their even share of it, over the rows by ``prior`` (V,)."""
    n_speeds = b.shape[0]
    out_w = n_refs - len(cols)
    density = elsewhere * np.asarray(prior, np.float64) / out_w if out_w > 0 else np.zeros(n_speeds)
    pos = np.clip(np.searchsorted(cols, new), 0, max(len(cols) - 1, 0))
    kept = (cols[pos] == new) if len(cols) else np.zeros(len(new), bool)
    out = np.repeat(density[:, None], len(new), axis=1)
    out[:, kept] = b[:, pos[kept]]
    held = float(out.sum())
    total = float(b.sum()) + elsewhere
    return out, max(total - held, 0.0)
