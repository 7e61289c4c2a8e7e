"""A large route searched around an index's candidates: the synthetic scale route and stream, the matcher's
state held compact, references first seen late, the sequence query."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from vpr_edge_bench.synthetic import plan_stream, write_route, write_stream
from vpr_edge.evaluation.truth import load_csv
from vpr_edge.index.ivf import SequenceQuery
from vpr_edge.matchers import MATCHERS
from vpr_edge.matchers.road import RoadMatcher
from vpr_edge.matchers.stream_config import StreamConfig


def test_stream_plan_has_its_detours_stop_and_far_reentry() -> None:
    p = plan_stream(100_000, 1000, seed=3)
    off = ~p.mapped
    assert off.sum() == 60 and not off[:250].any() and off[250:280].all() and off[700:730].all()
    assert p.stopped.sum() == 20 and p.stopped[500:520].all() and np.ptp(p.place[500:520]) == 0
    assert abs(p.place[730] - p.place[249]) > 40_000          # the second detour re-enters far away
    steps = np.diff(p.place[:250])
    assert set(np.round(steps, 3)) <= {0.5, 1.0, 1.5, 2.0, 3.0}


def test_route_and_stream_files_round_trip(tmp_path: Path) -> None:
    route, queries, truth = tmp_path / "r.npy", tmp_path / "q.npy", tmp_path / "t.csv"
    write_route(route, 5000, 32, seed=1)
    refs = np.load(route, allow_pickle=False)
    assert refs.shape == (5000, 32) and refs.dtype == np.float16
    np.testing.assert_allclose(np.linalg.norm(refs.astype(np.float32), axis=1), 1.0, atol=2e-3)
    alike = np.sum(refs[1:].astype(np.float32) * refs[:-1], axis=1)
    assert 0.8 < np.median(alike) < 0.97                     # consecutive places alike (rho 0.9)
    plan = plan_stream(5000, 200, seed=1)
    write_stream(route, plan, queries, truth, noise=0.5, seed=1)
    q = np.load(queries, allow_pickle=False)
    t = load_csv(truth)[:, 0]
    assert q.shape == (200, 32) and (t >= 0).tolist() == plan.mapped.tolist()
    on = np.flatnonzero(t >= 0)
    best = np.argmax(q[on].astype(np.float32) @ refs.astype(np.float32).T, axis=1)
    assert np.mean(np.abs(best - t[on]) <= 2) > 0.9          # low noise: each frame near its place
    a, b = np.flatnonzero(plan.stopped)[[0, -1]]
    stop = q[a:b + 1].astype(np.float32)
    assert np.all(stop[1:] @ stop[0] > 0.7) and not np.allclose(stop[1], stop[0])   # new exposures


def test_a_large_route_searched_around_candidates_holds_no_whole_route_state() -> None:
    n = 200_000
    m = RoadMatcher(n, StreamConfig.of(MATCHERS["stream-rules"].params))
    rng = np.random.default_rng(0)
    for t in range(30):
        refs = m.around(np.array([1000 + 2 * t, 150_000, int(rng.integers(n))]))
        sims = rng.normal(0.0, 0.05, len(refs))
        sims[np.abs(refs - (1000 + 2 * t)) <= 0] += 0.5
        ref, _ = m.update(sims, refs)
    assert abs(ref - 1058) <= 1
    assert m._full is None                                     # never the (speeds, positions) array
    assert m._vals.nbytes < 100_000
    assert m.ranking()[ref] == m.h.max(axis=0).reshape(n, -1).max(axis=1)[ref] > 0


def test_a_reference_first_seen_late_starts_from_the_prior() -> None:
    params = MATCHERS["stream-rules"].params
    m = RoadMatcher(1000, StreamConfig.of(params))
    m._t = 500                                                 # 500 frames elsewhere on the route
    first = m._normalise(np.full(3, 4.0), 10, 0.0, 1.0)
    second = m._normalise(np.full(3, 4.0), 10, 0.0, 1.0)
    np.testing.assert_allclose(first, 4.0)
    # the first sighting weighs as at the first frame (1 / memory of the mean), not as the whole mean (which
    # would cancel the second frame's evidence there)
    np.testing.assert_allclose(second, 4.0 - 4.0 / params["memory"], rtol=1e-6)


def test_sequence_query_is_the_mean_of_the_last_frames() -> None:
    s = SequenceQuery(3)
    frames = np.eye(4, dtype=np.float32)
    s.push(frames[0])
    np.testing.assert_array_equal(s.query(), frames[0])
    for f in frames[1:]:
        s.push(f)
    np.testing.assert_allclose(s.query(), frames[1:].mean(axis=0))
    s.reset()
    s.push(frames[2])
    np.testing.assert_array_equal(s.query(), frames[2])
