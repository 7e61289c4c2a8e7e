"""The road (``stream``) matcher's local search: on a long route it reads a window around a firm lock, checks
the whole route now and then, finds a jump; against its plain loops (``helpers.naive_road_local``)."""
from __future__ import annotations

import numpy as np
import pytest

from helpers import naive_road_local, places_at_speeds, planted
from vpr_edge.matchers import MATCHERS, get_matcher
from vpr_edge.matchers.base import step
from vpr_edge.matchers.road import RoadMatcher
from vpr_edge.matchers.stream_config import StreamConfig


def test_local_search_follows_a_long_route_and_finds_a_jump() -> None:
    """On a large route the stream matcher searches a window around a firm lock (``wanted``), checks the
    whole route now and then, and re-locks after the vehicle turns up far away (a kidnap)."""
    rng = np.random.default_rng(4)
    places = np.concatenate([places_at_speeds([(1.0, 60), (3.0, 40), (0.0, 20), (0.5, 40)], start=100),
                             places_at_speeds([(2.0, 120)], start=2200)])
    sim = planted(rng, 3000, places, noise=0.3)
    matcher = get_matcher("stream-rules").with_params(window=50)
    online = matcher.stream(3000)
    asked, got = [], []
    for row in sim:
        asked.append(online.wanted())
        got.append(step(online, lambda idx, row=row: row if idx is None else row[idx]))
    refs = np.array([r for r, _ in got])
    local = np.array([a is not None for a in asked])
    assert local.mean() > 0.5                                    # most frames read a window, not the route
    assert all(len(a) == 101 + 512 for a in asked if a is not None and 50 <= a[0] and a[100] < 2950)
    first, after = slice(10, 160), slice(200, None)
    assert np.mean(np.abs(refs[first] - places[first]) <= 1) > 0.95
    assert np.mean(np.abs(refs[after] - places[after]) <= 1) > 0.95   # found again within 40 frames
    # full rows give the same answers: the matcher takes what its window needs
    again = matcher.stream(3000)
    assert [again.update(row) for row in sim] == got
    # the evaluation path (run_online) is the same path
    assert list(matcher.run(sim).refs) == list(refs)


def test_local_search_is_off_on_small_routes() -> None:
    m = RoadMatcher(400, StreamConfig.of(MATCHERS["stream-rules"].params | {"window": 100}))
    for row in planted(np.random.default_rng(0), 400, np.arange(100, 150)):
        m.update(row)
        assert m.wanted() is None
    m = RoadMatcher(3000, StreamConfig.of(MATCHERS["stream-rules"].params | {"window": 50}))
    with pytest.raises(ValueError):
        m.update(np.zeros(10), np.arange(10))   # refs not asked for


def test_road_matcher_local_search_against_plain_loops() -> None:
    """A 60-place route long enough for the local search (window 5): the vectorised matcher, fed only the
    similarities it asks for (``step``), answers as the loops do, frame by frame, with most frames local and
    some whole-route checks among them."""
    rng = np.random.default_rng(7)
    places = places_at_speeds([(1.0, 20), (0.0, 6), (2.0, 8), (1.0, 20)], start=3)
    sim = planted(rng, 60, places, noise=0.3)
    params = MATCHERS["stream-rules"].params | {"vmax": 2.0, "grid": 2, "window": 5, "probe": 16, "check": 8, "span": 2,
                                          "hold": 1.0, "memory": 6.0, "lock": 3.0, "rival_window": 2}
    got = MATCHERS["stream-rules"].with_params(**params).run(sim, k=1)
    want = naive_road_local(sim, **params)
    assert list(got.refs) == [r for r, _, _ in want]
    np.testing.assert_allclose(got.scores, [c for _, c, _ in want], atol=1e-5)
    local = np.array([x for _, _, x in want])
    assert local.mean() > 0.5 and (~local[20:]).any()          # mostly local, with whole-route checks
