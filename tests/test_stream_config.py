"""The stream matcher's configuration (``stream_config.StreamConfig``): read from ``params.STREAM_RULES``, checked
once, with the one-line messages the matcher gives."""
from __future__ import annotations

import re

import pytest

from vpr_edge.matchers import get_matcher
from vpr_edge.matchers.params import STREAM_RULES, defaults
from vpr_edge.matchers.road import RoadMatcher
from vpr_edge.matchers.stream_config import StreamConfig


def test_the_defaults_round_trip() -> None:
    config = StreamConfig.default()
    assert config.params() == defaults(STREAM_RULES) == get_matcher("stream-rules").params
    assert StreamConfig.of(config.params()) == config
    assert (config.model.decay, config.search.window, config.rules.lock) == \
        (STREAM_RULES["decay"].default, STREAM_RULES["window"].default, STREAM_RULES["lock"].default)
    with pytest.raises(TypeError):   # every parameter is needed
        StreamConfig.of({k: v for k, v in defaults(STREAM_RULES).items() if k != "turn"})


@pytest.mark.parametrize("bad,message", [
    ({"decay": 2.0}, "decay must be in (0, 1), got 2.0"),
    ({"stop_gain": 1.5}, "need stop_gain in [0, 1] and stop_decay in (0, 1), got 1.5, 0.95"),
    ({"still": -0.1}, "still must be in [0, 1] (0: no motion cue), got -0.1"),
    ({"probe": 1}, "need grid >= 1, vmax >= 0, memory >= 1, window >= 0, probe >= 2 (got 2, 4.0, 50.0, 100, 1)"),
    ({"unique": 1.0}, "unique must be in [0, 1), got 1.0"),
    ({"confirm": 0}, "confirm must be at least 1, got 0"),
    ({"trust": 0.0}, "trust must be in (0, 1] (1: off), got 0.0"),
])
def test_a_bad_value_is_refused_in_one_line(bad: dict, message: str) -> None:
    with pytest.raises(ValueError) as config_error:
        StreamConfig.of(defaults(STREAM_RULES) | bad)
    assert str(config_error.value) == message
    with pytest.raises(ValueError) as registry_error:   # the registry's factory builds the same config
        get_matcher("stream-rules").with_params(**bad).stream(10)
    assert str(registry_error.value) == message
    with pytest.raises(ValueError, match=re.escape(message)):   # as --param reports it
        get_matcher("stream-rules").parse_params([f"{k}={v}" for k, v in bad.items()])


def test_the_matcher_takes_the_config_and_the_map() -> None:
    m = RoadMatcher(10, StreamConfig.default(), reach=30)
    assert m.config == StreamConfig.default() and m.verdict.rules.rival_window == 30
    with pytest.raises(ValueError, match="need at least one reference"):
        RoadMatcher(0, StreamConfig.default())
