"""The matcher registry and the contract every matcher keeps: result shapes, ranked candidates, refusals,
parameters parsed from ``--param KEY=VALUE``."""
from __future__ import annotations

import numpy as np
import pytest

from helpers import places_at_speeds, planted
from vpr_edge.matchers import MATCHERS, get_matcher


@pytest.mark.parametrize("name", list(MATCHERS))
def test_every_matcher_keeps_the_contract(name: str) -> None:
    rng = np.random.default_rng(4)
    places = places_at_speeds([(1.0, 30)], start=0)
    sim = planted(rng, 30, places, noise=0.2)
    res = MATCHERS[name].run(sim, k=5)
    assert res.refs.shape == (30,) and res.scores.shape == (30,) and res.ranked.shape == (30, 5)
    np.testing.assert_array_equal(res.ranked[:, 0], res.refs)
    assert all(len(set(row)) == 5 for row in res.ranked) or name.startswith("seqslam")
    assert np.isfinite(res.scores).all()
    assert np.mean(np.abs(res.refs[10:] - places[10:]) <= 1) > 0.7
    with pytest.raises(ValueError):
        MATCHERS[name].run(np.zeros(5))
    with pytest.raises(ValueError):
        get_matcher(name).with_params(no_such_parameter=1)


def test_unknown_matcher() -> None:
    with pytest.raises(ValueError, match="choose from"):
        get_matcher("nope")


def test_parse_params_reads_each_default_type_and_refuses_bad_items() -> None:
    stream, dtw = get_matcher("stream-rules"), get_matcher("dtw-open")
    assert stream.parse_params(["bias=1.6", "lock = 7", "window=0", "stop-gain=0.5"]) == \
        {"bias": 1.6, "lock": 7.0, "window": 0, "stop_gain": 0.5}
    assert dtw.parse_params(["hubs=false", "open_ends=1", "variant=similarity"]) == \
        {"hubs": False, "open_ends": True, "variant": "similarity"}
    assert stream.parse_params([]) == {}
    for bad, needle in ((["bias"], "KEY=VALUE"), (["nope=1"], "KEY=VALUE"), (["lock=abc"], "not a number"),
                        (["grid=1.5"], "not an int"), (["bias=nan"], "not a number"), (["decay=2"], "decay"),
                        (["hubs=maybe"], "not a bool")):
        matcher = dtw if bad[0].startswith("hubs") else stream
        with pytest.raises(ValueError, match=needle):
            matcher.parse_params(bad)
    with pytest.raises(ValueError, match="unknown DTW variant"):
        dtw.parse_params(["variant=fastest"])


def test_a_matcher_declares_the_search_its_instances_make() -> None:
    """What ``evaluate`` reads off the registry (whether whole-route rows may be coarse) is what ``Localizer``
    reads off an instance, for every registered matcher."""
    for m in MATCHERS.values():
        assert m.searches_locally == (m.online and m.stream(60).searches_locally), m.name
