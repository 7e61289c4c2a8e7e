"""Which places the stream matcher's next frame searches (``road.RoadMatcher``'s search policy, as pure
functions): the whole route, a window around a firm lock (``local_next``), or, on a map with an index, the
neighbourhoods of the index's candidates and of the best hypotheses held (``around_candidates``,
``best_hypotheses``). The module docstring of ``road`` says why each exists.
"""
from __future__ import annotations

import numpy as np

from vpr_edge.matchers.constants import PEAK_POOL, PEAK_SPACING
from vpr_edge.matchers.route import Intervals, RouteGraph, merge


def local_next(held_for: int, check: int, span: int) -> bool:
    """Whether the next frame searches around the answer, after ``held_for`` firmly locked frames in a row
    (0: the last frame was not): yes, except ``span`` frames in every ``check``, which search the whole route
    (so that a stronger hypothesis elsewhere is found)."""
    return held_for > 0 and held_for % check < check - span


def best_hypotheses(values: np.ndarray, where: np.ndarray | None, peaks: int, reach: int) -> list[int]:
    """The places of the ``peaks`` best hypotheses held: over the best trajectory score of each place
    (``values``, (n,), one per place of ``where``, sorted; None: places 0..n-1), the highest positive ones,
    chosen greedily among the ``PEAK_POOL`` * ``peaks`` highest, each more than ``PEAK_SPACING`` * ``reach``
    places from a better one chosen. In order of score."""
    values = np.asarray(values)
    if not len(values):
        return []
    k = min(len(values), PEAK_POOL * peaks)
    top = np.argpartition(-values, k - 1)[:k]
    chosen: list[int] = []
    for i in top[np.argsort(-values[top], kind="stable")]:
        if values[i] <= 0.0 or len(chosen) == peaks:
            break
        p = int(i) if where is None else int(where[i])
        if all(abs(p - c) > PEAK_SPACING * reach for c in chosen):
            chosen.append(p)
    return chosen


def around_candidates(graph: RouteGraph, candidates: np.ndarray, seek: int, hypotheses: list[int], reach: int,
                      gap: int) -> Intervals:
    """The places a frame searches on a map with an index: those within ``seek`` of each of the index's
    ``candidates`` along the route, and within ``reach`` of each of the ``hypotheses`` held
    (``best_hypotheses``); merged, windows closer than ``gap`` places searched as one."""
    near = [iv for c in np.unique(np.asarray(candidates, np.int64)) for iv in graph.near(int(c), seek)]
    return merge(near + [iv for p in hypotheses for iv in graph.near(p, reach)], gap)
