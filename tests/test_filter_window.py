"""The stream filter's local search (``matchers.filter_motion.Window``): on a window of every place it is the
whole-route motion model; on a part it keeps the mass; the filter that reads windows answers as the one that
reads every place, reading far fewer similarities."""
from __future__ import annotations

import numpy as np
import pytest

from vpr_edge.matchers.base import run_online
from vpr_edge.matchers.bayes import BayesFilter, FilterConfig
from vpr_edge.matchers.filter_motion import Transitions, Window, regather
from vpr_edge.matchers.params import STREAM
from vpr_edge.matchers.route import RouteGraph


def config(**overrides) -> FilterConfig:
    return FilterConfig.of({k: p.default for k, p in STREAM.items()} | overrides)


def graph() -> RouteGraph:
    """Three drives of 30, 25 and 35 places; the first's last places join the third's first."""
    return RouteGraph(90, np.array([0, 30, 55]), ((np.array([28, 29]), np.array([55, 56])),))


@pytest.mark.parametrize("step", [1.0, 0.5])
def test_a_window_of_every_place_is_the_whole_route_model(step: float) -> None:
    rng = np.random.default_rng(1)
    g, cfg = graph(), config(jump=0.01, leave=0.02, enter=0.1, speed_step=step)
    whole = Transitions(g, cfg)
    b = rng.random((len(Transitions(g, cfg).moves), g.n_refs))
    b /= b.sum() * 1.25
    want_b, want_off = whole.predict(b, 0.2)
    got_b, got_off, got_else = Window(g, np.arange(g.n_refs), whole.moves, whole.prior).predict(
        b, 0.2, 0.0, cfg.leave, cfg.jump, cfg.enter, whole.kernel)
    np.testing.assert_allclose(got_b, want_b, atol=1e-15)
    assert abs(got_off - want_off) < 1e-12 and got_else == 0.0


@pytest.mark.parametrize("step", [1.0, 0.5])
def test_a_window_keeps_the_mass_and_matches_the_whole_route_inside(step: float) -> None:
    """Mass held only inside the window: after one step the window's columns are the whole-route model's,
    save the share carried in from elsewhere, and window + elsewhere + off-map sum to what they did."""
    rng = np.random.default_rng(2)
    g, cfg = graph(), config(jump=0.0, leave=0.0, enter=0.0, speed_step=step)
    cols = np.arange(10, 40)
    n_v = len(Transitions(g, cfg).moves)
    b = np.zeros((n_v, g.n_refs))
    b[:, 20:26] = rng.random((n_v, 6))
    b /= b.sum() * 1.25
    whole = Transitions(g, cfg)
    want_b, want_off = whole.predict(b, 0.2)
    got_b, got_off, got_else = Window(g, cols, whole.moves, whole.prior).predict(b[:, cols], 0.2, 0.0, 0.0, 0.0,
                                                                                  0.0, whole.kernel)
    np.testing.assert_allclose(got_b, want_b[:, cols], atol=1e-15)
    assert abs(got_b.sum() + got_off + got_else - 1.0) < 1e-12
    assert abs(got_off - want_off) < 1e-12


def test_regather_moves_mass_between_windows() -> None:
    rng = np.random.default_rng(3)
    b = rng.random((5, 20))
    prior = np.array([0.4, 0.05, 0.25, 0.2, 0.1])
    cols, new = np.arange(100, 120), np.arange(110, 140)
    out, elsewhere = regather(b, cols, 0.3, new, 1000, prior)
    assert out.shape == (5, 30)
    np.testing.assert_array_equal(out[:, :10], b[:, 10:])
    assert abs(out.sum() + elsewhere - (b.sum() + 0.3)) < 1e-12
    np.testing.assert_allclose(out[:, 10:], np.repeat(0.3 * prior[:, None] / 980, 20, axis=1))   # by the prior


@pytest.mark.parametrize("step", [1.0, 0.5])
def test_elsewhere_feeds_a_window_as_the_whole_route_model_would(step: float) -> None:
    """Mass spread outside the window as ``elsewhere`` spreads it (every place alike, the rows by the prior):
    one step on, the window's columns are the whole-route model's (the prior is the speeds' long run, so the
    speed changes keep it)."""
    g, cfg = graph(), config(jump=0.0, leave=0.0, enter=0.0, speed_step=step)
    whole = Transitions(g, cfg)
    cols = np.arange(10, 40)
    outside = np.setdiff1d(np.arange(g.n_refs), cols)
    b = np.zeros((len(whole.moves), g.n_refs))
    b[:, cols] = np.random.default_rng(4).random((len(whole.moves), len(cols))) * 0.01
    b[:, outside] = 0.3 * whole.prior[:, None] / len(outside)
    want_b, want_off = whole.predict(b, 0.2)
    got_b, got_off, got_else = Window(g, cols, whole.moves, whole.prior).predict(
        b[:, cols], 0.2, 0.3, 0.0, 0.0, 0.0, whole.kernel)
    np.testing.assert_allclose(got_b, want_b[:, cols], atol=1e-15)
    assert abs(got_b.sum() + got_off + got_else - (b.sum() + 0.2)) < 1e-12


def long_route(rng, n: int, truth: np.ndarray) -> tuple[np.ndarray, BayesFilter, BayesFilter]:
    """A noisy similarity matrix (frames, n) whose frame i shows place ``truth[i]`` (and a little the next),
    with a filter reading a window of 40 places and one reading every place."""
    sim = rng.normal(0.0, 0.05, (len(truth), n))
    sim[np.arange(len(truth)), truth] += 0.25
    sim[np.arange(len(truth)), truth + 1] += 0.12
    return sim, BayesFilter(n, config(window=40, probe=256)), BayesFilter(n, config(window=0))


def test_the_filter_reading_windows_answers_as_the_whole_route_filter() -> None:
    """A long route (2,000 places, a window of 40): a noisy drive at one place a frame. The local filter reads
    the window and probe on most frames and gives the whole-route filter's answers."""
    rng = np.random.default_rng(4)
    n, truth = 2000, 500 + np.arange(300)
    sim, local, whole = long_route(rng, n, truth)
    read, answers = [], []
    for row in sim:
        want = local.wanted()
        read.append(n if want is None else len(want))
        answers.append(local.update(row if want is None else row[want], want)[0])
    ref = run_online(whole, sim, k=1).refs
    assert np.mean(np.array(read) < n) > 0.8
    assert np.mean(np.array(answers) == np.asarray(ref)) > 0.98
    assert np.mean(np.abs(np.array(answers) - truth)[50:] <= 1) > 0.98


def test_on_a_map_with_an_index_the_state_never_spans_the_route() -> None:
    """The same long route with an index (``step`` with candidates): a frame that would read the whole route
    reads around the index's candidates and the places held. The answers are the whole-route filter's, no
    frame reads every place, and a re-entry far along the route is found through the candidates."""
    from vpr_edge.matchers.base import step

    rng = np.random.default_rng(5)
    n, truth = 2000, np.r_[500 + np.arange(150), 1500 + np.arange(150)]   # a jump far along the route at 150
    sim, local, whole = long_route(rng, n, truth)
    read, answers = [], []
    for i, row in enumerate(sim):
        decoys = rng.integers(0, n, 5)
        candidates = lambda: np.r_[truth[i] + rng.integers(-2, 3), decoys]   # an index: right among decoys
        got = {}

        def rows(refs, row=row):
            got["n"] = n if refs is None else len(refs)
            return row if refs is None else row[refs]

        answers.append(step(local, rows, None, candidates)[0])
        read.append(got["n"])
        assert local.cols is not None and len(local.cols) < n
    ref = run_online(whole, sim, k=1).refs
    assert max(read) < n
    assert np.mean(np.array(answers) == np.asarray(ref)) > 0.95
    assert np.mean(np.abs(np.array(answers) - truth)[np.r_[20:150, 170:300]] <= 1) > 0.98
