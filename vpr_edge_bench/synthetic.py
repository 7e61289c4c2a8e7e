"""A synthetic route of global descriptors at any scale, and a hard stream over it, written as the files a user
of another network holds (``.npy`` rows, the project's ground-truth CSV): what the scale benchmark
(the ``bench-scale`` experiment) and its tests run ``build-map``, ``localize`` and the scoring on.

The route: ``n_places`` unit descriptors of ``dim`` dims, each place ``rho`` like the one before (a road's
consecutive places look alike), generated and written a block at a time (never the whole matrix in memory).
The stream (``plan_stream``): a cold start somewhere on the route, speed changes between 0.5 and 3 places a
frame, a detour off the map re-entering a little further on, a long stop made of new exposures (a camera at a
red light), and a second detour re-entering far away; off-map frames are a walk of their own, as alike from
frame to frame as the route's. Each mapped frame is its place's descriptor plus Gaussian noise of ``noise``
(relative to a unit descriptor): at the default (5.5, with 512 dims and ``rho`` 0.9) a frame alone finds its
place (top 1) about 1 time in 4 on a million places.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vpr_edge.evaluation.metrics import runs
from vpr_edge.evaluation.truth import write_ground_truth
from vpr_edge.files.atomic import atomic_output

BLOCK = 65_536   # descriptors generated and written at a time


@dataclass(frozen=True)
class StreamPlan:
    """A stream over a route of ``n_places``: per frame (Q,) its place (float, on the route; NaN: off the
    map) and whether the camera stands."""

    place: np.ndarray
    stopped: np.ndarray

    @property
    def mapped(self) -> np.ndarray:
        """(Q,) bool: the frame's place is on the map."""
        return ~np.isnan(self.place)

    def truth(self) -> list[list[int]]:
        """Per frame its correct place (a list of one index; empty off the map), as ground truth lists."""
        return [[] if np.isnan(p) else [int(p)] for p in self.place]


def plan_stream(n_places: int, n_frames: int, seed: int = 0) -> StreamPlan:
    """The hard stream's layout (module docstring) for ``n_frames`` frames (>= 100) over ``n_places``: a
    detour of 3% of the frames at 25% (re-entering 1.5 detour-lengths on), a stop of 2% at 50%, a second
    detour at 70% re-entering half the route away; speeds from {0.5, 1, 1.5, 2, 3} places a frame held for
    50-300 frames. Positions wrap at the route's end."""
    if n_frames < 100 or n_places < 10:
        raise ValueError(f"need at least 100 frames and 10 places, got {n_frames} and {n_places}")
    rng = np.random.default_rng([seed, 2])
    detour = max(1, round(0.03 * n_frames))
    events = {round(0.25 * n_frames): ("detour", 1.5 * detour), round(0.5 * n_frames): ("stop", 0.0),
              round(0.7 * n_frames): ("detour", 0.5 * n_places)}
    place = np.full(n_frames, np.nan)
    stopped = np.zeros(n_frames, bool)
    pos = rng.uniform(0.1, 0.3) * n_places
    speed, until, t = 1.0, 0, 0
    while t < n_frames:
        if t in events:
            what, jump = events[t]
            n = detour if what == "detour" else max(1, round(0.02 * n_frames))
            n = min(n, n_frames - t)
            if what == "stop":
                place[t:t + n] = pos
                stopped[t:t + n] = True
            pos = (pos + jump) % n_places
            t += n
            continue
        if t >= until:
            speed = float(rng.choice([0.5, 1.0, 1.5, 2.0, 3.0]))
            until = t + int(rng.integers(50, 301))
        place[t] = pos
        pos = (pos + speed) % n_places
        t += 1
    return StreamPlan(place, stopped)


def _walk(rng: np.random.Generator, n: int, dim: int, rho: float, first: np.ndarray | None) -> np.ndarray:
    """(n, dim) float32 rows, each ``rho`` times the one before plus fresh noise (unit variance kept), the
    first following ``first`` (dim,) if given; not normalised."""
    x = rng.standard_normal((n, dim), dtype=np.float32)
    fresh = np.float32(np.sqrt(1.0 - rho ** 2))
    prev = first
    for i in range(n):
        if prev is not None:
            x[i] *= fresh
            x[i] += np.float32(rho) * prev
        prev = x[i]
    return x


def _unit(x: np.ndarray) -> np.ndarray:
    return x / np.maximum(np.linalg.norm(x, axis=-1, keepdims=True), 1e-12)


def write_route(path: str | os.PathLike[str], n_places: int, dim: int = 512, rho: float = 0.9, seed: int = 0,
                dtype: str = "float16") -> None:
    """Write the route's (n_places, dim) unit descriptors to ``path`` (.npy of ``dtype``), a block at a time
    (written to a temporary file and renamed)."""
    rng = np.random.default_rng([seed, 1])
    with atomic_output(Path(path)) as tmp:
        out = np.lib.format.open_memmap(tmp, mode="w+", dtype=np.dtype(dtype), shape=(n_places, dim))
        prev = None
        for lo in range(0, n_places, BLOCK):
            raw = _walk(rng, min(BLOCK, n_places - lo), dim, rho, prev)
            prev = raw[-1].copy()
            out[lo:lo + len(raw)] = _unit(raw)
        out.flush()
        del out


def write_stream(route: str | os.PathLike[str], plan: StreamPlan, queries: str | os.PathLike[str],
                 truth: str | os.PathLike[str], noise: float = 5.5, stop_noise: float = 0.6, rho: float = 0.9,
                 seed: int = 0) -> None:
    """Write the stream ``plan`` over the route file ``route`` (``write_route``): ``queries`` (Q, dim) .npy of
    the route's dtype (each mapped frame its place's descriptor plus noise of ``noise``, relative to a unit
    descriptor; a stopped frame the stop's first frame plus noise of ``stop_noise``, relative to that frame,
    a new exposure: cosine about 0.86 to it at the default, where consecutive moving frames have about 0.03); off-map frames a walk of their own plus
    noise) and ``truth``, the ground-truth CSV (an empty field off the map)."""
    refs = np.load(route, mmap_mode="r", allow_pickle=False)
    dim = refs.shape[1]
    rng = np.random.default_rng([seed, 3])
    off = plan.mapped == 0
    wild = _unit(_walk(rng, int(off.sum()), dim, rho, None))   # the world off the map, a road of its own
    q = np.empty((len(plan.place), dim), np.float32)
    q[off] = wild
    on = np.flatnonzero(plan.mapped)
    q[on] = refs[plan.place[on].astype(np.int64)].astype(np.float32)
    q += noise / np.sqrt(dim) * rng.standard_normal(q.shape, dtype=np.float32)
    q = _unit(q)
    for a, b in runs(plan.stopped):   # a standing camera: new exposures of the stop's first view
        q[a + 1:b] = _unit(q[a] + stop_noise / np.sqrt(dim) * rng.standard_normal((b - a - 1, dim), np.float32))
    with atomic_output(Path(queries)) as tmp:
        with open(tmp, "wb") as f:
            np.save(f, q.astype(refs.dtype), allow_pickle=False)
    write_ground_truth(truth, plan.truth())
