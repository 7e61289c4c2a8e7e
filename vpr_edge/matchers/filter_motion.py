"""The stream filter's motion model (``bayes``, step 1): over the whole route (``Transitions``), or over a
window of places around its answer on a long route (``Window``), the rest of the on-map mass held as one
number spread evenly (*elsewhere*); and what the motion cue says of the speed (``cue_weights``, step 3).

Speeds are 0 (standing) and one place a frame to ``vmax`` in steps of ``speed_step`` (0.5: 1, 1.5, 2, ..).
A speed between two whole places moves the camera by the nearer whole numbers of places, each as often as
the speed lies near it (1.5: one place or two, half the time each). Below one place a frame a camera shows
a place again; the motion cue reads such a frame as standing, so a slow vehicle is followed as stops and
moves (a slow speed of its own let a trajectory linger by a look-alike: docs/decisions.md).

On a route of more than ``4 * window`` places the filter reads only the places within ``window`` of a firm
answer (and a fixed probe sample for the row's median and spread), as ``stream``'s local search does; every
``check`` frames it reads the whole route for ``span`` frames, and it reads it whenever the answer is not
firm. ``Window`` moves the mass it holds one frame on with the same motion model as the whole-route
``Transitions``; what leaves the window joins *elsewhere*, what enters it comes from there. On a
window of every place it is ``Transitions`` exactly (tested).
"""
from __future__ import annotations

import math

import numpy as np

from vpr_edge.matchers.constants import (CUE_FLOOR, CUE_MOVING_SD, CUE_STANDING, FROM_ANOTHER_DRIVE, FROM_ELSEWHERE,
                                         GO_BLIND, JOIN)
from vpr_edge.matchers.filter_config import FilterConfig
from vpr_edge.matchers.route import RouteGraph

Steps = list[list[tuple[int, float]]]   # per speed: (places moved in a frame, its probability)


def speed_values(vmax: int, step: float) -> np.ndarray:
    """The speeds followed, places a frame (V,): 0, then 1 to ``vmax`` in steps of ``step`` (none but 0 when
    ``vmax`` is 0)."""
    if vmax < 1:
        return np.zeros(1)
    return np.r_[0.0, 1.0 + step * np.arange(int(round((vmax - 1) / step)) + 1)]


def speed_steps(speeds: np.ndarray) -> Steps:
    """Each speed (places a frame) -> the whole places it moves in a frame and their chances."""
    out: Steps = []
    for s in speeds:
        lo = int(math.floor(s + 1e-9))
        f = float(s) - lo
        out.append([(lo, 1.0)] if f < 1e-9 else [(lo, 1.0 - f), (lo + 1, f)])
    return out


def by_move(steps: Steps) -> list[tuple[int, np.ndarray]]:
    """``steps`` regrouped by the places moved: (places, each speed's chance of moving them (V,)), so the
    motion model shifts the mass once a distance, not once a speed."""
    moves = sorted({d for parts in steps for d, _ in parts})
    out = []
    for d in moves:
        w = np.array([sum(p for dd, p in parts if dd == d) for parts in steps])
        out.append((d, w))
    return out


def speed_kernel(n_speeds: int, change: float) -> np.ndarray:
    """(V, V) row-stochastic: from speed v to v'. A speed changes to the next one up or down with probability
    ``change`` each; at the ends a change that would leave the range stays."""
    k = np.zeros((n_speeds, n_speeds))
    for v in range(n_speeds):
        for w in (v - 1, v + 1):
            k[v, min(max(w, 0), n_speeds - 1)] += change
        k[v, v] += 1.0 - 2.0 * change
    return k


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


def blind(kernel: np.ndarray) -> np.ndarray:
    """A speed kernel (V, V) for frames with no motion cue: a stopped camera also starts again at one place
    a frame (speed 1, the second speed) with probability ``GO_BLIND``. With a cue, each moving frame tells
    the filter it moves; without one, broad evidence (neighbouring places alike) could hold it at speed 0
    while the camera drives on."""
    k = kernel.copy()
    one = min(1, len(k) - 1)
    k[0] *= 1.0 - GO_BLIND
    k[0, one] += GO_BLIND
    return k


class Transitions:
    """The motion model on a route graph: ``predict(b, off)`` moves the on-map mass ``b`` (V, R) and the
    off-map mass one frame on (``bayes`` module docstring, step 1)."""

    def __init__(self, graph: RouteGraph, config: FilterConfig) -> None:
        self.graph, self.config = graph, config
        self.speeds = speed_values(config.vmax, config.speed_step)
        self.n_speeds = len(self.speeds)
        self.steps = speed_steps(self.speeds)
        self.shifts = by_move(self.steps)
        self.kernel = speed_kernel(self.n_speeds, config.speed_change)
        self.blind_kernel = blind(self.kernel)   # frames with no motion cue
        later = [(int(s), int(e) + 1) for s, e in zip(graph.starts[1:], graph.ends[1:])]
        self.cut = {d: np.concatenate([np.arange(s, min(s + d, e)) for s, e in later]).astype(np.int64)
                    if later else np.zeros(0, np.int64) for d in range(1, int(math.ceil(config.vmax)) + 2)}

    def entry(self) -> np.ndarray:
        """Where mass coming onto the map lands: (V, R), every place and speed alike, summing to 1."""
        return np.full((self.n_speeds, self.graph.n_refs), 1.0 / (self.n_speeds * self.graph.n_refs))

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
        for d, w in self.shifts:   # w (V,): each speed's chance of moving d places
            wc = w[:, None]
            if d == 0:
                moved += wc * b
                continue
            if d >= r:
                ran += float(w @ b.sum(axis=1))
                continue
            moved[:, d:] += wc * b[:, :-d]
            ran += float(w @ b[:, r - d:].sum(axis=1))
            cc = self.cut[d]
            if len(cc):   # came from another drive's end: off the map instead
                came = wc * b[:, cc - d]
                moved[:, cc] -= came
                ran += float(came.sum())
        for sources, targets in self.graph.junctions:
            share = moved[:, sources].sum(axis=1) * JOIN
            moved[:, sources] *= 1.0 - JOIN
            moved[:, targets] += (share / len(targets))[:, None]
        on = float(moved.sum())
        out = moved * (1.0 - leave - jump)
        out += (jump * on + enter * off) / out.size   # onto every place and speed alike (``entry``)
        return out, off * (1.0 - enter) + leave * on + ran


class Window:
    """The places ``cols`` (sorted int64 (W,)) of ``graph`` held at the speeds of ``steps``: for each whole
    step d and column, where its mass comes from (``src[d]``: a column, or ``FROM_*``), and whether moving d
    places leaves the map (``exit_off[d]``: past its drive's end) or the window (``exit_else[d]``)."""

    def __init__(self, graph: RouteGraph, cols: np.ndarray, steps: Steps,
                 shifts: list[tuple[int, np.ndarray]] | None = None) -> None:
        self.graph, self.cols, self.steps = graph, np.asarray(cols, np.int64), steps
        self.shifts = by_move(steps) if shifts is None else shifts   # (``by_move(steps)``, made once a route)
        starts = np.asarray(graph.starts, np.int64)
        k = np.searchsorted(starts, self.cols, side="right") - 1
        first, last = starts[k], graph.ends[k]
        d = np.arange(max(p for parts in steps for p, _ in parts) + 1)[:, None]
        before, after = self.cols[None, :] - d, self.cols[None, :] + d
        pos, inside = self.positions(before)
        self.src = np.where(before < first, FROM_ANOTHER_DRIVE, np.where(inside, pos, FROM_ELSEWHERE))
        self.exit_off = after > last
        self.exit_else = ~self.exit_off & ~self.positions(after)[1]
        self.joins = [(self.positions(s)[0][self.positions(s)[1]], self.positions(t)[0][self.positions(t)[1]],
                       len(t)) for s, t in graph.junctions]

    def positions(self, places: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Places (any shape) -> (their columns, clipped; whether the window holds them)."""
        pos = np.clip(np.searchsorted(self.cols, places), 0, len(self.cols) - 1)
        return pos, self.cols[pos] == places

    def predict(self, b: np.ndarray, off: float, elsewhere: float, leave: float, jump: float, enter: float,
                kernel: np.ndarray) -> tuple[np.ndarray, float, float]:
        """(V, W) window mass, the off-map and elsewhere masses -> the same one frame on (sums kept)."""
        r, w = self.graph.n_refs, len(self.cols)
        n_speeds = len(self.steps)
        density = elsewhere / (n_speeds * (r - w)) if r > w else 0.0
        b = kernel.T @ b
        moved = np.zeros_like(b)
        ran = came_in = 0.0
        for d, share in self.shifts:   # share (V,): each speed's chance of moving d places
            src = self.src[d]
            got = b[:, np.maximum(src, 0)]
            got[:, src < 0] = 0.0
            from_else = src == FROM_ELSEWHERE
            got[:, from_else] = density
            moved += share[:, None] * got
            came_in += float(share.sum()) * density * int(from_else.sum())
            ran += float(share @ b[:, self.exit_off[d]].sum(axis=1))
            elsewhere += float(share @ b[:, self.exit_else[d]].sum(axis=1))
        elsewhere -= came_in
        for sources, targets, n_targets in self.joins:
            share = moved[:, sources].sum(axis=1) * JOIN
            moved[:, sources] *= 1.0 - JOIN
            if len(targets):
                moved[:, targets] += (share / n_targets)[:, None]
            elsewhere += float(share.sum()) * (n_targets - len(targets)) / n_targets
        on = float(moved.sum()) + elsewhere
        spread = jump * on + enter * off
        out = moved * (1.0 - leave - jump) + spread / (n_speeds * r)
        elsewhere = elsewhere * (1.0 - leave - jump) + spread * (r - w) / r
        return out, off * (1.0 - enter) + leave * on + ran, max(elsewhere, 0.0)


def regather(b: np.ndarray, cols: np.ndarray, elsewhere: float, new: np.ndarray,
             n_refs: int) -> tuple[np.ndarray, float]:
    """Mass (V, W) held at places ``cols`` and ``elsewhere`` -> the same held at places ``new``: columns
    leaving join elsewhere, columns entering take their even share of it."""
    n_speeds = b.shape[0]
    out_w = n_refs - len(cols)
    density = elsewhere / (n_speeds * out_w) if out_w > 0 else 0.0
    pos = np.clip(np.searchsorted(cols, new), 0, max(len(cols) - 1, 0))
    kept = (cols[pos] == new) if len(cols) else np.zeros(len(new), bool)
    out = np.full((n_speeds, len(new)), density)
    out[:, kept] = b[:, pos[kept]]
    held = float(out.sum())
    total = float(b.sum()) + elsewhere
    return out, max(total - held, 0.0)
