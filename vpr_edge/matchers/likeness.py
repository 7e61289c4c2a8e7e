"""How far along a route its references stay alike: the reach a rival trajectory must lie beyond.

The ``stream-rules`` matcher's uniqueness compares the best trajectory with the best one ending more than
``rival_window`` references from it. On a map sampled densely (a camera's every frame, a slow drive) a
reference a few places on still resembles the answer's, so a trajectory ending there collects part of the
answer's evidence, and a right answer's uniqueness falls with the map's density rather than with its
ambiguity. ``reach`` measures that density on the map itself: the smallest lag k at which references k
apart along the route are, by their median cosine, no more alike than the median of unrelated references'
cosines plus one standard deviation of them (unrelated: at least ``MAX_LAG`` apart, or half the sample on a
short map). Pairs inside one run of standing references (``motion.route_stands``: the drive stood, one view)
are left out, as that likeness is a stop, not the map's density. Estimated on the route's first ``SAMPLE``
references in the map's order (a map's density is the camera's and the drive's, not the place's; on a map of
several short drives some pairs span two drives, read as unrelated), capped at ``MAX_LAG``: opening
a map pays one pass over up to ``PAIRS`` pairs per lag up to the reach (milliseconds on a map whose references
differ within a few places, a few hundred on one that stays alike for ``MAX_LAG``).
"""
from __future__ import annotations

from collections.abc import Iterable, Iterator

import numpy as np

from vpr_edge.matchers.constants import MAX_LAG, PAIRS, SAMPLE


class LikenessSample:
    """The route's first ``SAMPLE`` references (unit rows), kept while its blocks stream past (``feed``) for
    ``reach``."""

    def __init__(self) -> None:
        self._rows: list[np.ndarray] = []
        self._n = 0

    def feed(self, blocks: Iterable[np.ndarray]) -> Iterator[np.ndarray]:
        """Pass the blocks (n, D) on unchanged, keeping unit copies of the first ``SAMPLE`` rows."""
        for block in blocks:
            if self._n < SAMPLE:
                x = np.asarray(block[:SAMPLE - self._n], np.float32)
                norm = np.linalg.norm(x, axis=1, keepdims=True)
                self._rows.append(np.divide(x, norm, out=np.zeros_like(x), where=norm > 0))
                self._n += len(x)
            yield block

    def reach(self, stands: np.ndarray | None = None) -> int:
        """The lag (references) beyond which references are no more alike than unrelated ones (module
        docstring); ``stands``: the route's standing references (R,) bool, or None. 0 for a map too short to
        tell (under 8 references)."""
        if not self._rows:
            return 0
        return reach(np.concatenate(self._rows), None if stands is None else np.asarray(stands, bool)[:self._n])


def reach(x: np.ndarray, stands: np.ndarray | None = None) -> int:
    """Unit references (M, D) in route order and their standing flags (M,) bool (None: none stand) -> the
    lag at which references stop being alike (module docstring), 1..``MAX_LAG``; 0 when M < 8."""
    m = len(x)
    if m < 8:
        return 0
    run = np.arange(m) if stands is None else np.cumsum(~stands)   # one id per run of one view
    far = min(MAX_LAG, m // 2)
    rng = np.random.default_rng(0)
    i = rng.integers(0, m - far, PAIRS)
    j = i + far + rng.integers(0, m - far - i)      # at least far apart, within the sample (m - far >= 4)
    unrelated = np.einsum("ij,ij->i", x[i], x[j])
    line = float(np.median(unrelated) + np.std(unrelated))

    def alike(k: int) -> bool:
        a = np.arange(0, m - k, max(1, (m - k) // PAIRS))
        a = a[run[a] != run[a + k]]
        return len(a) >= 4 and float(np.median(np.einsum("ij,ij->i", x[a], x[a + k]))) > line

    return next((k for k in range(1, far) if not alike(k)), far)
