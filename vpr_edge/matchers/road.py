"""The streaming matcher for a vehicle on the road: any speed, stops, lock-on from anywhere, a lost state.

State: for every position on the route (a grid of 1/``grid`` reference steps) and every speed in
0, 1/grid, ..., ``vmax`` references per frame, the score H of the best recent trajectory ending there
(a decayed local-alignment sum in the manner of Smith-Waterman):

    H_t(v, p) = max(0, decay * max_v' [H_{t-1}(v', p - v) - turn * |v - v'| * grid] + z_t(p) - bias)

z_t is the frame's similarity row normalised twice: z-scored over the references (so that a frame whose
similarities are all low, as across seasons, counts as much as one whose are all high), then each
reference's running mean z over the last ~``memory`` frames is subtracted (frames while the best
trajectory is stopped are left out of that mean, so a long stop does not wash out its own place). The second step removes hubs:
references that resemble every query (a plain wall, a tunnel) would otherwise collect evidence while the
vehicle moves on, and a stopped trajectory parked on one beats the moving true one (measured: stream
R@1 0.41 -> 0.73 on nordland-dev). ``bias`` is what a frame must beat to extend a trajectory; ``turn`` charges
each change of speed; ``decay`` forgets evidence older than about 1 / (1 - decay) frames. The max(0, .) lets
a trajectory start anywhere (lock-on from anywhere, re-lock after a detour) and floors hopeless ones.
Speed 0 is a state, so a stopped vehicle is followed; speed changes are cheap but not free, so
trajectories stay straight where the evidence allows (what makes SeqSLAM work) and bend where the vehicle
speeds up or slows down.

The answer is the position of the best state. Its score does two jobs, so it has two parts:

    score = [H_best >= lock] + uniqueness,   uniqueness = 1 - (H_rival + 1) / (H_best + 1)  in [0, 1)

H_best is about the summed excess of z over ``bias`` along the last ~1/(1 - decay) frames: below ``lock``
no trajectory fits well enough and the frame is lost (the registry's min_confidence is 1.0: "locked").
H_rival is the best trajectory ending more than ``rival_window`` references away: like SeqSLAM's
best/second-best ratio, uniqueness ranks frames by how unambiguous the answer is, which H alone does badly
(measured on nordland-dev, AUC 0.51 -> 0.73 on the aligned stream; H still decides lost better: at 5%
of mapped frames lost, 80% of unmapped ones are lost by H, 7% by uniqueness). So locked frames rank above
lost ones, each by uniqueness, and ``--min-confidence`` between 1 and 2 asks for a locked and unambiguous
answer.

The max over speeds with the speed penalty is a distance transform (two passes over the speeds), so a frame
costs O(grid * speeds * R) vectorised work in preallocated buffers, and the state is (grid * speeds + 1) * R
floats, whatever the stream's length.
"""
from __future__ import annotations

import numpy as np


class RoadMatcher:
    """Online matcher over (position, speed) trajectories; see the module docstring."""

    def __init__(self, n_refs: int, vmax: float = 4.0, grid: int = 2, decay: float = 0.9, bias: float = 1.0,
                 turn: float = 1.0, memory: float = 50.0, lock: float = 5.0, rival_window: int = 10) -> None:
        if n_refs < 1:
            raise ValueError("need at least one reference")
        if not 0.0 < decay < 1.0:
            raise ValueError(f"decay must be in (0, 1), got {decay}")
        if grid < 1 or vmax < 0 or memory < 1:
            raise ValueError(f"need grid >= 1, vmax >= 0, memory >= 1 (got {grid}, {vmax}, {memory})")
        self.n_refs, self.grid, self.decay, self.bias = n_refs, grid, decay, bias
        self.turn, self.memory, self.lock, self.rival_window = turn, memory, lock, max(0, int(rival_window))
        self.n_speeds = int(round(vmax * grid)) + 1
        # float32: the per-frame passes over (speeds x positions) are memory-bound; halving the bytes halved
        # the time at 100,000 references (tools/bench_matcher.py)
        self.h = np.zeros((self.n_speeds, n_refs * grid), np.float32)
        self._m = np.empty_like(self.h)   # buffers reused every frame
        self._z = np.empty(n_refs * grid, np.float32)
        self._mean = np.zeros(n_refs)     # running mean z per reference
        self._stopped = False
        self._weight = memory             # decayed number of frames in it: starts as if `memory` frames of mean 0

    def _normalise(self, s: np.ndarray) -> np.ndarray:
        """Similarity row (R,) -> z-scored over references, minus each reference's running mean."""
        z = (s - s.mean()) / max(float(s.std()), 1e-12)
        out = z - self._mean
        if not self._stopped:   # frames of a stopped vehicle repeat one place: they say nothing of hubs
            self._weight = (1.0 - 1.0 / self.memory) * self._weight + 1.0
            self._mean += (z - self._mean) / self._weight
        return out

    def _spread(self) -> np.ndarray:
        """max over v' of H(v', p) - turn * |v - v'| for every v: forward and backward passes over speeds."""
        m = self._m
        np.copyto(m, self.h)
        for v in range(1, self.n_speeds):
            np.maximum(m[v], m[v - 1] - self.turn, out=m[v])
        for v in range(self.n_speeds - 2, -1, -1):
            np.maximum(m[v], m[v + 1] - self.turn, out=m[v])
        return m

    def update(self, sim_row: np.ndarray) -> tuple[int, float]:
        """Similarities (R,) of the new frame -> (reference at the best state, score in [0, 2); >= 1: locked)."""
        s = np.asarray(sim_row, np.float64)
        if s.shape != (self.n_refs,):
            raise ValueError(f"similarity row must have shape ({self.n_refs},), got {s.shape}")
        z = self._z.reshape(self.n_refs, self.grid)
        z[:] = self._normalise(s)[:, None]
        z -= self.bias
        m = self._spread()
        h = self.h
        for v in range(self.n_speeds):   # a trajectory at speed v came from v grid steps behind
            h[v, v:] = m[v, : m.shape[1] - v]
            h[v, :v] = 0.0
        h *= self.decay
        np.maximum(h, 0.0, out=h)
        h += self._z
        np.maximum(h, 0.0, out=h)
        flat = int(np.argmax(h))
        self._stopped = flat < h.shape[1]          # the best trajectory has speed 0
        ref, best = (flat % h.shape[1]) // self.grid, float(h.flat[flat])
        per_ref = self.ranking()
        w = self.rival_window
        rival = max(float(per_ref[: max(0, ref - w)].max(initial=0.0)), float(per_ref[ref + w + 1:].max(initial=0.0)))
        return ref, float(best >= self.lock) + 1.0 - (rival + 1.0) / (best + 1.0)

    def ranking(self) -> np.ndarray:
        """Best trajectory score ending at each reference (R,)."""
        return self.h.max(axis=0).reshape(self.n_refs, self.grid).max(axis=1)

    def reset(self) -> None:
        """Forget the stream."""
        self.h[:] = 0.0
        self._mean[:] = 0.0
        self._stopped = False
        self._weight = self.memory
