"""Streaming DTW (the first streaming matcher): one decayed accumulated-cost row over the references."""
from __future__ import annotations

import numpy as np

from vpr_edge.matchers.base import WholeRoute

from vpr_edge.matchers.dtw import row_scan


class StreamingDTW(WholeRoute):
    """DTW over an unbounded stream with O(R) work and O(R) memory per frame.

    The distance form is used (step term 1 - cos): every step costs, so paths cannot run ahead along the
    references for free, which the similarity form would reward once the path's end is open. Each cell
    holds the best path cost ending there, with the previous frame's cost discounted by ``decay`` (0 < decay
    < 1; memory of about 1 / (1 - decay) frames), so evidence from before the vehicle left the mapped route
    fades and a path re-forms wherever it re-enters. The path may begin at any reference.

    Known limits (docs/results.md, "Evaluating"): skipping a reference costs its full 1 - cos, so it cannot follow a
    vehicle faster than the map's spacing; staying put costs nothing extra. Kept as a baseline.

    ``update`` returns the reference at the end of the cheapest path and a score: the decayed mean cosine
    similarity along that path (1 = perfect, lower = less confident).
    """

    def __init__(self, n_refs: int, *, decay: float) -> None:
        if n_refs < 1:
            raise ValueError("need at least one reference")
        if not 0.0 < decay < 1.0:
            raise ValueError(f"decay must be in (0, 1), got {decay}")
        self.n_refs = n_refs
        self.decay = decay
        self.cost = np.zeros(n_refs, np.float64)      # decayed path cost ending at each reference
        self.weight = np.zeros(n_refs, np.float64)    # decayed number of steps on that path
        self.frames = 0

    def update(self, sim_row: np.ndarray, refs: None = None, still: float | None = None) -> tuple[int, float]:
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
        cost, k = row_scan(1.0 - s, entry_c, np.minimum)
        self.weight = entry_w[k] + (np.arange(self.n_refs) - k + 1)
        self.cost = cost
        self.frames += 1
        best = int(np.argmin(cost))
        return best, float(1.0 - cost[best] / self.weight[best])

    def ranking(self) -> np.ndarray:
        """Negated path cost ending at each reference."""
        return -self.cost

    def reset(self) -> None:
        """Forget the stream (e.g. after a long gap)."""
        self.cost[:] = 0.0
        self.weight[:] = 0.0
        self.frames = 0
