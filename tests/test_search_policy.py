"""The stream matcher's search policy (``matchers.search_policy``) against plain loops: when the next frame
searches locally, which hypotheses are kept, which places a frame searches around an index's candidates."""
from __future__ import annotations

import numpy as np
import pytest

from vpr_edge.matchers.constants import PEAK_POOL, PEAK_SPACING
from vpr_edge.matchers.route import RouteGraph
from vpr_edge.matchers.search_policy import around_candidates, best_hypotheses, local_next


@pytest.mark.parametrize("check, span", [(100, 5), (10, 1), (3, 0), (5, 5)])
def test_local_next_searches_the_whole_route_span_frames_in_every_check(check: int, span: int) -> None:
    """Counting firmly locked frames one by one: of every ``check`` in a row, ``span`` search the whole route,
    the rest locally; a frame that is not firm sends the next to the whole route and starts the count again."""
    firm = [True] * 250 + [False] + [True] * 30
    held, local = 0, []
    for f in firm:
        held = held + 1 if f else 0
        local.append(local_next(held, check, span))
    assert local[250] is False
    run = local[:250]
    for start in range(0, 250 - check + 1):
        assert run[start:start + check].count(False) == span, (start, check, span)
    assert local[251:] == run[:len(local) - 251]   # the count starts again


def naive_hypotheses(values: np.ndarray, where: np.ndarray | None, peaks: int, reach: int) -> list[int]:
    places = list(range(len(values))) if where is None else [int(p) for p in where]
    ranked = sorted(zip(values, places), key=lambda vp: -vp[0])[:PEAK_POOL * peaks]
    chosen: list[int] = []
    for v, p in ranked:
        if v <= 0 or len(chosen) == peaks:
            break
        if all(abs(p - c) > PEAK_SPACING * reach for c in chosen):
            chosen.append(p)
    return chosen


@pytest.mark.parametrize("seed", range(6))
def test_best_hypotheses_against_a_sort(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 400))
    values = rng.normal(0, 1, n) * rng.integers(0, 2, n)   # some exact zeros, some negative
    where = None if seed % 2 else np.sort(rng.choice(5000, n, replace=False))
    peaks, reach = int(rng.integers(1, 10)), int(rng.integers(0, 30))
    assert best_hypotheses(values, where, peaks, reach) == naive_hypotheses(values, where, peaks, reach)
    assert best_hypotheses(np.zeros(0), None, peaks, reach) == []


def test_around_candidates_against_a_set() -> None:
    """On a map of three drives with junctions: the places searched are exactly those within ``seek`` of a
    candidate or ``reach`` of a hypothesis along the route, gaps shorter than ``gap`` filled."""
    graph = RouteGraph(300, [0, 100, 180], ((np.array([99]), np.array([180])), (np.array([299]), np.array([100]))))
    rng = np.random.default_rng(4)
    for _ in range(20):
        candidates = rng.integers(0, 300, int(rng.integers(1, 8)))
        hypotheses = [int(p) for p in rng.integers(0, 300, int(rng.integers(0, 4)))]
        seek, reach, gap = int(rng.integers(0, 12)), int(rng.integers(0, 25)), int(rng.integers(0, 6))
        got = around_candidates(graph, candidates, seek, hypotheses, reach, gap)
        want = {q for c in candidates for lo, hi in graph.near(int(c), seek) for q in range(lo, hi)}
        want |= {q for p in hypotheses for lo, hi in graph.near(p, reach) for q in range(lo, hi)}
        covered = {q for lo, hi in got for q in range(lo, hi)}
        assert want <= covered
        extra = sorted(covered - want)   # only gaps of fewer than ``gap`` places between searched ones
        for q in extra:
            below = max(p for p in want if p < q)
            above = min(p for p in want if p > q)
            assert above - below - 1 < gap, (q, below, above, gap)
        assert all(a[1] < b[0] for a, b in zip(got, got[1:]))   # sorted, disjoint
