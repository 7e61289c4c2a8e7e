"""SeqSLAM (Milford & Wyeth, ICRA 2012) as a baseline, with OpenSeqSLAM's parameter names.

The difference matrix is D = -(local contrast of the similarities) shifted to be non-negative (SeqSLAM's
enhanced difference matrix, OpenSeqSLAM's ``r_window`` for the enhancement window). A trajectory is a
straight line through ``ds`` + 1 query frames at a constant speed v in [``vmin``, ``vmax``] references per
frame (speeds in steps of 1/ds, reference offsets floor(k * v)); its value is the sum of D along it. The
best trajectory gives the match; the score is 1 - (best value / best value of trajectories whose reference
lies more than ``match_window``//2 from it), SeqSLAM's ratio test turned so that higher = more confident.

* ``seqslam`` (offline, as published): the window of query frames is centred on the frame being matched
  (shifted inwards at the ends of the sequence), trajectories start at every reference.
* ``seqslam-online``: the window is the current frame and the ``ds`` before it; trajectories end at every
  reference; a ring of ``ds`` + 1 enhanced rows is all the memory. The fair peer of a streaming matcher.

Both are vectorised over references and speeds; the offline form loops over query frames.
"""
from __future__ import annotations

import numpy as np

from vpr_edge.matchers.base import Result, WholeRoute, lead_with, top_k
from vpr_edge.matchers.contrast import local_contrast


def speeds(ds: int, vmin: float, vmax: float) -> np.ndarray:
    """Trajectory speeds (V,) in references per frame: multiples of 1/ds from vmin to vmax."""
    if ds < 1 or vmin > vmax or vmin < 0:
        raise ValueError(f"need ds >= 1 and 0 <= vmin <= vmax (got ds={ds}, vmin={vmin}, vmax={vmax})")
    moves = np.arange(int(np.ceil(vmin * ds - 1e-9)), int(np.floor(vmax * ds + 1e-9)) + 1)
    return moves / ds


def _offsets(ds: int, vmin: float, vmax: float) -> np.ndarray:
    """(V, ds + 1) int: reference offset of each trajectory k frames from its origin."""
    return np.floor(np.arange(ds + 1)[None, :] * speeds(ds, vmin, vmax)[:, None] + 1e-9).astype(np.int64)


def _ratio_score(values: np.ndarray, best: int, match_window: int) -> float:
    """1 - best / best-outside-the-window for trajectory values (R,) (lower = better)."""
    far = np.abs(np.arange(len(values)) - best) > match_window // 2
    if not far.any():
        return 0.0
    second = float(values[far].min())
    return 1.0 - float(values[best]) / second if second > 0 else 0.0


def enhanced_difference(sim: np.ndarray, r_window: int) -> np.ndarray:
    """SeqSLAM's contrast-enhanced difference matrix (Q, R), shifted so that its minimum is 0."""
    d = -local_contrast(sim, r_window)
    return d - d.min()


def seqslam_match(sim: np.ndarray, k: int = 10, *, ds: int, vmin: float, vmax: float, r_window: int,
                  match_window: int) -> Result:
    """Offline SeqSLAM over ``sim`` (Q, R) with a window centred on each frame (its parameters and their
    defaults: ``params.SEQSLAM``)."""
    d = enhanced_difference(sim, r_window)
    q, r = d.shape
    length = min(ds + 1, q)
    off = _offsets(ds, vmin, vmax)[:, :length]                                  # (V, L)
    v = speeds(ds, vmin, vmax)
    ys = np.minimum(np.arange(r)[None, None, :] + off[:, :, None], r - 1)       # (V, L, R) by start
    rows = np.arange(length)[None, :, None]
    refs = np.empty(q, np.int64)
    scores = np.empty(q)
    ranked = np.empty((q, min(k, r)), np.int64)
    for n in range(q):
        x0 = min(max(n - ds // 2, 0), q - length)
        sums = d[x0:x0 + length][rows, ys].sum(axis=1)                          # (V, R)
        vbest = sums.argmin(axis=0)
        values = sums[vbest, np.arange(r)]                                       # (R,) by start reference
        pos = np.minimum(np.arange(r) + np.floor((n - x0) * v[vbest] + 1e-9).astype(np.int64), r - 1)
        start = int(values.argmin())
        refs[n] = pos[start]
        scores[n] = _ratio_score(values, start, match_window)
        ranked[n] = pos[top_k(-values, k)]
    return Result(refs, scores, lead_with(refs, ranked))


class SeqSLAMOnline(WholeRoute):
    """SeqSLAM over the past ``ds`` + 1 frames only: trajectories end at the current frame."""

    def __init__(self, n_refs: int, *, ds: int, vmin: float, vmax: float, r_window: int,
                 match_window: int) -> None:
        self.n_refs, self.r_window, self.match_window = n_refs, r_window, match_window
        off = _offsets(ds, vmin, vmax)                                           # (V, ds+1), k frames back
        self._ys = np.maximum(np.arange(n_refs)[None, None, :] - off[:, :, None], 0)  # (V, ds+1, R)
        self._ring = np.zeros((ds + 1, n_refs))                                  # row k: k frames back
        self._frames = 0
        self._values = np.zeros(n_refs)

    def update(self, sim_row: np.ndarray, refs: None = None, still: float | None = None) -> tuple[int, float]:
        """Similarities (R,) of the new frame -> (reference at the end of the best trajectory, ratio score)."""
        d = -local_contrast(sim_row, self.r_window)
        self._ring[1:] = self._ring[:-1]
        self._ring[0] = d - d.min()
        self._frames += 1
        length = min(self._frames, len(self._ring))
        sums = self._ring[np.arange(length)[None, :, None], self._ys[:, :length]].sum(axis=1)   # (V, R)
        self._values = sums.min(axis=0)
        best = int(self._values.argmin())
        return best, _ratio_score(self._values, best, self.match_window)

    def ranking(self) -> np.ndarray:
        """Negated best trajectory value ending at each reference."""
        return -self._values

    def reset(self) -> None:
        """Forget the stream."""
        self._ring[:] = 0.0
        self._frames = 0
