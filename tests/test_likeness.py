"""How far along a map its references stay alike (``matchers.likeness.reach``) against a loop, and the rival
window it gives the road (``stream``) matcher on a densely sampled map."""
from __future__ import annotations

import numpy as np
import pytest

from vpr_edge.matchers import get_matcher
from vpr_edge.matchers.constants import MAX_LAG
from vpr_edge.matchers.likeness import reach


def naive_reach(x: np.ndarray, stands: np.ndarray | None) -> int:
    """``likeness.reach`` as plain loops over every pair (maps short enough that it reads every pair)."""
    m = len(x)
    run, r = [], 0
    for s in (np.zeros(m, bool) if stands is None else stands):
        r += not s
        run.append(r)
    far = min(MAX_LAG, m // 2)
    rng = np.random.default_rng(0)
    i = rng.integers(0, m - far, 2048)
    j = np.minimum(i + far + rng.integers(0, m - far - i), m - 1)
    unrelated = [float(x[a] @ x[b]) for a, b in zip(i, j)]
    line = np.median(unrelated) + np.std(unrelated)
    for k in range(1, far):
        pairs = [float(x[a] @ x[a + k]) for a in range(m - k) if run[a] != run[a + k]]
        if len(pairs) >= 4 and np.median(pairs) <= line:
            return k
    return far


@pytest.mark.parametrize("rho, stops", [(0.0, False), (0.6, False), (0.9, False), (0.9, True)])
def test_reach_against_a_loop_and_with_the_maps_density(rho: float, stops: bool) -> None:
    """The lag at which references stop being alike: as plain loops; longer the more alike consecutive
    references are; a run of one view (the drive stood) does not lengthen it."""
    rng = np.random.default_rng(7)
    x = rng.normal(size=(600, 32))
    for i in range(1, len(x)):
        x[i] = rho * x[i - 1] + np.sqrt(1 - rho ** 2) * x[i]
    stands = np.zeros(len(x), bool)
    if stops:   # the drive stood at ten places for 20 frames each: one view repeated
        for s in range(30, 600, 60):
            x[s + 1:s + 21] = x[s]
            stands[s + 1:s + 21] = True
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    got = reach(x.astype(np.float32), stands)
    assert got == naive_reach(x, stands)
    expected = {0.0: (1, 1), 0.6: (2, 6), 0.9: (8, 30)}[rho]
    assert expected[0] <= got <= expected[1], got
    if stops:
        assert got <= reach(x.astype(np.float32), None)   # read as density, the stops would lengthen it


def test_a_densely_sampled_map_keeps_its_right_answers_unique() -> None:
    """On a map whose references stay alike for ~20 places (a slow drive, every frame kept), a right answer's
    nearest rivals share its evidence: read on the map (``on_route``: its reach), the rival lies beyond them and
    the uniqueness floor keeps the right answers; with the fixed rival window alone it loses some."""
    rng = np.random.default_rng(2)
    n, d = 1500, 48
    refs = rng.normal(size=(n, d))
    for i in range(1, n):
        refs[i] = 0.9 * refs[i - 1] + np.sqrt(1 - 0.81) * refs[i]
    refs /= np.linalg.norm(refs, axis=1, keepdims=True)
    truth = (100 + np.arange(300) * 1.5).astype(int)
    q = refs[truth] + 0.12 * rng.normal(size=(300, d))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    sim = q @ refs.T
    m = get_matcher("stream-rules")
    on_map = m.on_route([refs.astype(np.float32)])
    assert on_map.reach > m.params["rival_window"]
    kept = {}
    for name, matcher in (("reach", on_map), ("fixed", m)):
        res = matcher.run(sim)
        kept[name] = ((np.abs(res.refs - truth) <= 2) & (res.scores >= 1.0))[20:].mean()
    assert kept["reach"] > 0.97 and kept["reach"] > kept["fixed"] + 0.05, kept
