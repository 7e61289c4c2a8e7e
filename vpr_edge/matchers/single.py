"""Best single match: per frame the most similar reference, no sequence information (the baseline)."""
from __future__ import annotations

import numpy as np

from vpr_edge.matchers.base import WholeRoute


class BestMatch(WholeRoute):
    """Online best single match; the score is the cosine similarity of the chosen pair."""

    def __init__(self, n_refs: int) -> None:
        self.n_refs = n_refs
        self._row = np.zeros(n_refs)

    def update(self, sim_row: np.ndarray, refs: None = None, still: float | None = None) -> tuple[int, float]:
        """Similarities (R,) -> (argmax, its similarity)."""
        self._row = np.asarray(sim_row, np.float64)
        best = int(np.argmax(self._row))
        return best, float(self._row[best])

    def ranking(self) -> np.ndarray:
        """The last similarity row itself."""
        return self._row

    def reset(self) -> None:
        """Nothing to forget but the last row."""
        self._row = np.zeros(self.n_refs)
