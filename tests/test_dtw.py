"""DTW (both variants, open ends, hub removal), best single match and streaming DTW against plain loops and on
planted routes."""
from __future__ import annotations

import numpy as np
import pytest

from helpers import places_at_speeds, planted
from vpr_edge.matchers import get_matcher
from vpr_edge.matchers.dtw import dtw_accumulate, dtw_align, remove_hubs
from vpr_edge.matchers.params import DTW
from vpr_edge.matchers.stream_dtw import StreamingDTW


def cosine_similarity(queries: np.ndarray, refs: np.ndarray) -> np.ndarray:
    """(Q, D) x (R, D) -> (Q, R) cosine similarities, the test streams' similarity matrices."""
    q = queries / np.linalg.norm(queries, axis=1, keepdims=True)
    r = refs / np.linalg.norm(refs, axis=1, keepdims=True)
    return q @ r.T


MAX_STEP = DTW["max_step"].default


def best_match(sim: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    result = get_matcher("single").run(sim, k=1)
    return result.refs, result.scores


def naive_accumulate(sim: np.ndarray, variant: str, open_ends: bool = False) -> np.ndarray:
    term = sim if variant == "similarity" else 1.0 - sim
    better = max if variant == "similarity" else min
    q, r = sim.shape
    acc = np.zeros((q, r))
    for i in range(q):
        for j in range(r):
            prev = [acc[a, b] for a, b in ((i - 1, j - 1), (i - 1, j), (i, j - 1)) if a >= 0 and b >= 0]
            if i == 0 and (j == 0 or open_ends):
                prev.append(0.0)           # a path may start here
            acc[i, j] = term[i, j] + better(prev)
    return acc


def naive_path(acc: np.ndarray, variant: str, open_ends: bool = False) -> list[tuple[int, int]]:
    pick = np.argmax if variant == "similarity" else np.argmin
    i, j = acc.shape[0] - 1, (int(pick(acc[-1])) if open_ends else acc.shape[1] - 1)
    path = [(i, j)]
    while (i, j) != (0, 0):
        if i == 0:
            if open_ends and pick([0.0, acc[0, j - 1]]) == 0:
                break
            j -= 1
        elif j == 0:
            i -= 1
        else:
            step = int(pick([acc[i - 1, j - 1], acc[i - 1, j], acc[i, j - 1]]))
            i, j = [(i - 1, j - 1), (i - 1, j), (i, j - 1)][step]
        path.append((i, j))
    return path[::-1]


@pytest.mark.parametrize("open_ends", [False])
@pytest.mark.parametrize("variant", ["similarity", "distance"])
@pytest.mark.parametrize("shape", [(1, 1), (1, 9), (9, 1), (7, 13), (20, 20), (31, 17)])
def test_dtw_matches_naive(variant: str, shape: tuple[int, int], open_ends: bool) -> None:
    rng = np.random.default_rng(sum(shape))
    sim = rng.uniform(-1, 1, size=shape)
    want = naive_accumulate(sim, variant, open_ends)
    np.testing.assert_allclose(dtw_accumulate(sim, variant=variant, open_ends=open_ends, max_step=MAX_STEP), want,
                               rtol=1e-10, atol=1e-10)
    result = dtw_align(sim, variant=variant, open_ends=open_ends, max_step=MAX_STEP)
    path = naive_path(want, variant, open_ends)
    np.testing.assert_array_equal(result.path, np.array(path))
    assert result.total == pytest.approx(want[path[-1]])
    for i in range(shape[0]):
        row_cells = [j for a, j in path if a == i]
        best = max(row_cells, key=lambda j: sim[i, j])
        assert sim[i, result.matches[i]] == sim[i, best] and result.scores[i] == sim[i, best]


@pytest.mark.parametrize("variant", ["similarity", "distance"])
def test_dtw_recovers_a_time_warped_route(variant: str) -> None:
    rng = np.random.default_rng(7)
    refs = rng.normal(size=(60, 32))
    truth = np.clip(np.round(np.cumsum(rng.uniform(0.4, 1.6, size=70))).astype(int) - 1, 0, 59)
    queries = refs[truth] + 0.5 * rng.normal(size=(70, 32))
    result = dtw_align(cosine_similarity(queries, refs), variant=variant, open_ends=False, max_step=MAX_STEP)
    assert np.mean(np.abs(result.matches - truth) <= 1) > 0.9


def test_subsequence_dtw_finds_a_clip_inside_a_long_route() -> None:
    rng = np.random.default_rng(8)
    refs = rng.normal(size=(200, 32))
    truth = np.arange(120, 150)
    sim = cosine_similarity(refs[truth] + 0.8 * rng.normal(size=(30, 32)), refs)
    clip = dtw_align(sim, variant="distance", open_ends=True, max_step=MAX_STEP)
    assert np.mean(np.abs(clip.matches - truth) <= 1) > 0.9
    assert clip.path[0, 1] >= 118 and clip.path[-1, 1] <= 152


def test_dtw_rejects_bad_input() -> None:
    with pytest.raises(ValueError):
        dtw_align(np.zeros((0, 3)), variant="distance", open_ends=False, max_step=MAX_STEP)
    with pytest.raises(ValueError):
        dtw_align(np.zeros((2, 3)), variant="cosine", open_ends=False, max_step=MAX_STEP)  # type: ignore[arg-type]


def test_best_match_and_cosine() -> None:
    rng = np.random.default_rng(0)
    q, r = rng.normal(size=(5, 8)), rng.normal(size=(9, 8))
    sim = cosine_similarity(q, r)
    want = np.array([[a @ b / np.linalg.norm(a) / np.linalg.norm(b) for b in r] for a in q])
    np.testing.assert_allclose(sim, want, atol=1e-12)
    idx, score = best_match(sim)
    np.testing.assert_array_equal(idx, want.argmax(axis=1))
    np.testing.assert_allclose(score, want.max(axis=1))


def naive_stream(rows: np.ndarray, decay: float) -> list[tuple[int, float]]:
    r = rows.shape[1]
    cost, weight = np.zeros(r), np.zeros(r)
    out = []
    for t, s in enumerate(rows):
        c = 1.0 - s
        new_c, new_w = np.zeros(r), np.zeros(r)
        for j in range(r):
            cands = [(decay * cost[j], decay * weight[j])]
            if t > 0 and j > 0:
                cands.append((decay * cost[j - 1], decay * weight[j - 1]))
            if j > 0:
                cands.append((new_c[j - 1], new_w[j - 1]))
            bc, bw = min(cands, key=lambda p: p[0])
            new_c[j], new_w[j] = c[j] + bc, 1 + bw
        cost, weight = new_c, new_w
        best = int(np.argmin(cost))
        out.append((best, 1.0 - cost[best] / weight[best]))
    return out


def test_streaming_dtw_matches_naive_recurrence() -> None:
    rng = np.random.default_rng(5)
    rows = rng.uniform(-1, 1, size=(40, 25))
    dtw = StreamingDTW(25, decay=0.8)
    got = [dtw.update(row) for row in rows]
    for (gi, gs), (wi, ws) in zip(got, naive_stream(rows, 0.8)):
        assert gi == wi and gs == pytest.approx(ws, abs=1e-9)


def synthetic_route(rng: np.random.Generator, refs: np.ndarray, truth: np.ndarray, noise: float) -> np.ndarray:
    """Query encodings along ``truth`` (-1 = off the mapped route: a random place)."""
    out = np.where((truth >= 0)[:, None], refs[np.maximum(truth, 0)], rng.normal(size=(len(truth), refs.shape[1])))
    return out + noise * rng.normal(size=out.shape)


def test_streaming_dtw_follows_route_leaves_and_recovers() -> None:
    rng = np.random.default_rng(11)
    refs = rng.normal(size=(300, 64))
    truth = np.concatenate([np.arange(20, 80), np.full(40, -1), np.arange(200, 260)])
    queries = synthetic_route(rng, refs, truth, noise=1.6)
    sim = cosine_similarity(queries, refs)
    dtw = StreamingDTW(300, decay=0.9)
    out = np.array([dtw.update(row) for row in sim])
    pred, score = out[:, 0].astype(int), out[:, 1]
    single = best_match(sim)[0]
    on_first, on_second = slice(10, 60), slice(110, 160)   # after 10 frames to lock on
    assert np.mean(np.abs(pred[on_first] - truth[on_first]) <= 1) > 0.95
    assert np.mean(np.abs(pred[on_second] - truth[on_second]) <= 1) > 0.95   # re-entered elsewhere
    assert np.mean(np.abs(single[on_second] - truth[on_second]) <= 1) < np.mean(
        np.abs(pred[on_second] - truth[on_second]) <= 1)                     # sequence beats single frames
    assert score[70:100].mean() < score[on_first].mean()                      # confidence drops off-route


def test_streaming_dtw_state_does_not_grow() -> None:
    dtw = StreamingDTW(50, decay=0.9)
    rng = np.random.default_rng(0)
    sizes = set()
    for _ in range(500):
        dtw.update(rng.uniform(-1, 1, 50))
        sizes.add((dtw.cost.nbytes, dtw.weight.nbytes))
    assert sizes == {(400, 400)}
    with pytest.raises(ValueError):
        dtw.update(np.zeros(49))
    with pytest.raises(ValueError):
        StreamingDTW(10, decay=1.0)


def test_remove_hubs_against_plain_loops() -> None:
    rng = np.random.default_rng(5)
    sim = rng.normal(size=(7, 9))
    want = np.empty_like(sim)
    for i, row in enumerate(sim):
        want[i] = (row - row.mean()) / row.std()
    for j in range(sim.shape[1]):
        want[:, j] -= want[:, j].mean()
    np.testing.assert_allclose(remove_hubs(sim), want, atol=1e-12)


def test_open_ends_dtw_is_not_caught_by_a_hub() -> None:
    """A reference alike to every query (stronger than the true matches): without hub removal the path
    stands on it, with it (the dtw-open preset) the path follows the vehicle."""
    rng = np.random.default_rng(6)
    places = places_at_speeds([(1.0, 30), (2.0, 30)], start=40)
    sim = planted(rng, 200, places, noise=0.3)
    sim[:, 5] += 1.3
    res = get_matcher("dtw-open").run(sim)
    assert np.mean(np.abs(res.refs - places) <= 1) > 0.9
    parked = get_matcher("dtw-open").with_params(hubs=False).run(sim)
    assert np.mean(parked.refs == 5) > 0.9


@pytest.mark.parametrize("speed", [2.0, 3.0])
def test_open_ends_dtw_follows_fast_vehicle(speed: float) -> None:
    rng = np.random.default_rng(int(speed))
    places = places_at_speeds([(speed, 40)], start=60)
    sim = planted(rng, 400, places, noise=0.5)
    res = get_matcher("dtw-open").run(sim)
    assert np.mean(np.abs(res.refs - places) <= 1) >= 0.85     # the first frames fix the start
    fixed = get_matcher("dtw").run(sim)
    assert np.mean(np.abs(fixed.refs - places) <= 1) < 0.5     # fixed ends cannot: the route is partial
