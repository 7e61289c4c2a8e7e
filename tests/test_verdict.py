"""The probability line (``matchers.verdict``, the ``stream-prob`` and ``stream-decoy`` matchers): each function
against a plain loop, and planted front ends whose right line is known."""
from __future__ import annotations

import numpy as np
import pytest

from vpr_edge.evaluation.scoring import evaluate_mode
from vpr_edge.matchers import get_matcher
from vpr_edge.matchers.motion import reversed_stands
from vpr_edge.matchers.verdict import (DecoyGate, RecentViews, TailScale, ViewFilter, block_peaks, expected_precision,
                                       line_score, local_best, near_values, place_probability, rival_weight,
                                       spacings, trajectory_probability, view_quantile)

MODES = ["stream-prob", "stream-decoy"]


def test_block_peaks_against_a_loop() -> None:
    rng = np.random.default_rng(0)
    values = rng.exponential(size=57)
    where = np.sort(rng.choice(200, 57, replace=False))
    exclude = [(30, 45), (150, 160)]
    peaks, blocks = block_peaks(values, where, 10, exclude)
    naive: dict[int, float] = {}
    for v, p in zip(values, where):
        if any(lo <= p < hi for lo, hi in exclude):
            continue
        naive[p // 10] = max(naive.get(p // 10, -np.inf), v)
    assert blocks.tolist() == sorted(naive)
    np.testing.assert_allclose(peaks, [naive[b] for b in sorted(naive)])



@pytest.mark.parametrize("exclude", [[], [(30, 45)], [(33, 36)], [(0, 12)], [(50, 57)], [(0, 57)], [(40, 40)]])
@pytest.mark.parametrize("width", [1, 7, 10])
def test_block_peaks_of_the_whole_route_against_a_loop(exclude: list[tuple[int, int]], width: int) -> None:
    """The whole route (``where`` None) less at most one interval: the fast path gives what the loop gives,
    a block cut by the interval counted once."""
    values = np.random.default_rng(1).exponential(size=57)
    peaks, blocks = block_peaks(values, None, width, exclude)
    naive: dict[int, float] = {}
    for p, v in enumerate(values):
        if not any(lo <= p < hi for lo, hi in exclude):
            naive[p // width] = max(naive.get(p // width, -np.inf), v)
    assert blocks.tolist() == sorted(naive)
    np.testing.assert_allclose(peaks, [naive[b] for b in sorted(naive)])
    ref_peaks, ref_blocks = block_peaks(values, np.arange(57), width, exclude)   # the general path
    np.testing.assert_array_equal(blocks, ref_blocks)
    np.testing.assert_array_equal(peaks, ref_peaks)

def test_spacings_estimate_an_exponential_tails_scale() -> None:
    """Renyi: the normalised spacings of exponential order statistics have the tail's scale as mean."""
    rng = np.random.default_rng(1)
    tail = TailScale(memory=1e9)
    for _ in range(400):
        tail.add(spacings(3.0 + rng.exponential(2.5, size=40)))
    assert tail.value == pytest.approx(2.5, rel=0.05)
    x = np.array([5.0, 3.0, 0.0, 2.0])   # zeros (floored trajectories) are left out
    np.testing.assert_allclose(spacings(x), [1 * (5 - 3), 2 * (3 - 2)])
    many = rng.exponential(size=50)   # more than the top 16: the loop over the 16 highest
    top = sorted(many, reverse=True)[:16]
    np.testing.assert_allclose(spacings(many, 16), [i * (top[i - 1] - top[i]) for i in range(1, 16)])


def test_trajectory_probability_is_a_softmax_over_rivals() -> None:
    rivals = np.array([1.0, 2.0, 0.0])
    p = trajectory_probability(rival_weight(5.0, rivals, 1.5))
    assert p == pytest.approx(1 / (1 + sum(np.exp((r - 5.0) / 1.5) for r in rivals)))
    assert trajectory_probability(rival_weight(5.0, rivals, None)) == 0.0   # no scale yet: nothing stands out


def test_local_best_and_view_quantile_against_loops() -> None:
    rng = np.random.default_rng(2)
    part = rng.normal(size=30)
    where = np.arange(100, 130)
    got = local_best(part, where, [(110, 115)])
    naive = [max(part[max(0, i - 1):i + 2]) for i in range(30) if not 110 <= where[i] < 115]
    np.testing.assert_allclose(got, naive)
    assert view_quantile(got, 10.0) == pytest.approx(1 / (len(got) + 1))
    assert view_quantile(got, -10.0) == 1.0
    whole = local_best(part, None, [(3, 6), (20, 22)])   # the whole route: places 0..29
    np.testing.assert_allclose(whole, [max(part[max(0, i - 1):i + 2]) for i in range(30)
                                       if not (3 <= i < 6 or 20 <= i < 22)])


def test_recent_views_against_a_loop() -> None:
    """Each place's mean over the frames that saw it (exponential memory per sighting), shrunk by the prior
    against the place's sightings so far, as it stood before the frame."""
    rng = np.random.default_rng(8)
    recent, n, memory, prior = RecentViews(12, memory=4.0, prior=1.0), 12, 4.0, 1.0
    sums, weights = np.zeros(n), np.zeros(n)   # naive: weighted sums of the sightings
    count = np.zeros(n)                         # and how many there were
    for _ in range(30):
        places = np.sort(rng.choice(n, 7, replace=False))
        z = rng.normal(size=7)
        mean = np.divide(sums, weights, out=np.zeros(n), where=weights > 0)
        np.testing.assert_allclose(recent.corrected(z, places), z - mean[places] * count[places] / (count[places] + prior))
        recent.add(z, places)
        for p, v in zip(places, z):
            count[p] += 1
            sums[p] = sums[p] * (1 - 1 / memory) + v
            weights[p] = weights[p] * (1 - 1 / memory) + 1
    everything = rng.normal(size=n)
    mean = sums / np.maximum(weights, 1e-12)
    np.testing.assert_allclose(recent.corrected(everything, slice(None)),
                               everything - mean * count / (count + prior))


def test_view_filter_believes_sharp_views_and_doubts_uniform_ones() -> None:
    rng = np.random.default_rng(3)
    f = ViewFilter()
    for _ in range(60):
        f.update(float(rng.uniform(0, 0.02)), teach=True)
    assert f.p > 0.99 and f.a < 0.3
    lost_after = next(i for i in range(20) if f.update(float(rng.uniform(0.3, 1.0)), teach=False) < 0.98)
    assert lost_after <= 2   # a sharp front end says at once that the view no longer fits


def planted(rng: np.random.Generator, n_refs: int, places: np.ndarray, signal: float, noise: float = 1.0) -> np.ndarray:
    """Rows (F, R): the true place (-1: none) raised by ``signal`` over independent noise."""
    sim = noise * rng.normal(size=(len(places), n_refs))
    on = places >= 0
    sim[np.flatnonzero(on), places[on]] += signal
    return sim


def run(sim: np.ndarray, places: np.ndarray, target: float = 0.98, mode: str = "stream-prob"):
    truth = np.where(places[:, None] >= 0, places[:, None], -1)
    return evaluate_mode(get_matcher(mode), sim, truth, tolerance=1, target_precision=target)


def test_decoy_gate_against_a_loop() -> None:
    """The gate opens where the exponential mean of (best - decoy) reaches ``line`` standard deviations of the
    last ``spread`` decoys, after ``warm`` frames (a plain loop)."""
    rng = np.random.default_rng(12)
    best = np.r_[rng.normal(5, 2, 60), rng.normal(15, 2, 60), rng.normal(5, 2, 60)]
    decoy = rng.normal(5, 2, len(best))
    gate, opened = DecoyGate(memory=10, line=1.0, spread=20, warm=5), []
    for b, d in zip(best, decoy):
        opened.append(gate.update(float(b), float(d)))
    want, total, weight = [], 0.0, 0.0
    for t in range(len(best)):
        total, weight = 0.9 * total + best[t] - decoy[t], 0.9 * weight + 1.0
        recent = decoy[max(0, t - 19):t + 1]
        want.append(t >= 4 and total / weight >= np.std(recent))
    assert opened == want
    assert np.mean(opened[:40]) < 0.15 and all(opened[80:120]) and np.mean(opened[150:]) < 0.15


def test_decoy_gate_leaves_frames_that_do_not_tell_out() -> None:
    """Frames that do not tell forwards from backwards (a standing camera, a best where the map shows one
    view) leave the gate as it was: it opens and closes as a gate fed only the telling frames does, and it
    waits for ``warm`` telling frames."""
    rng = np.random.default_rng(3)
    best = np.r_[rng.normal(5, 2, 40), rng.normal(15, 2, 40)]
    decoy = rng.normal(5, 2, len(best))
    telling = rng.random(len(best)) > 0.3
    telling[:4] = [False, False, True, False]
    wild = np.where(telling, decoy, 100.0)   # what a frame that does not tell shows: it must not count
    mixed, alone = DecoyGate(memory=10, line=1.0, spread=20, warm=2), DecoyGate(memory=10, line=1.0, spread=20, warm=2)
    got, want, last = [], [], False
    for b, d, w, t in zip(best, wild, decoy, telling):
        got.append(mixed.update(float(b), float(d), bool(t)))
        if t:
            last = alone.update(float(b), float(w))
        want.append(last)
    assert got == want
    assert not any(got[:4]) and any(got)   # shut until two frames have told


def test_reversed_stands_against_a_loop() -> None:
    route = np.array([False, True, True, False, False, True, False])   # references 1, 2 and 5 show the one before
    rev = reversed_stands(route)
    refs = list(range(len(route)))[::-1]             # the references in reverse order
    want = [False] + [bool(route[refs[i - 1]]) for i in range(1, len(refs))]   # shows the one before it there
    assert rev.tolist() == want


@pytest.mark.parametrize("mode", [*MODES, "stream"])
def test_the_same_probability_for_a_narrow_and_a_wide_band_of_cosines(mode: str) -> None:
    """A front end whose cosines all lie in 0.9-1.0 and one whose cosines spread over 0-1: the same answers,
    the same probabilities (``stream``: the same lock and uniqueness)."""
    rng = np.random.default_rng(4)
    places = np.r_[np.arange(10, 90), -np.ones(20, int), np.arange(100, 150)]
    sim = planted(rng, 160, places, 3.0)
    wide = (sim - sim.min()) / (sim.max() - sim.min())
    narrow = 0.9 + 0.1 * wide
    a, b = run(wide, places, mode=mode), run(narrow, places, mode=mode)
    assert np.array_equal(a.refs, b.refs)
    np.testing.assert_allclose(a.scores, b.scores, atol=1e-4)


@pytest.mark.parametrize("mode", MODES)
def test_a_strong_front_end_is_answered_at_the_target_and_leaves_the_map_at_once(mode: str) -> None:
    rng = np.random.default_rng(5)
    places = np.r_[np.arange(0, 120), -np.ones(30, int), np.arange(150, 250)]
    r = run(planted(rng, 260, places, 4.0), places, mode=mode)
    assert r.answered_right >= 0.98 and r.mapped_right >= 0.9
    assert r.lost_unmapped >= 0.95 and r.exit_frames[0] <= 3


@pytest.mark.parametrize("mode", [*MODES, "stream"])
def test_a_front_end_right_one_frame_in_four_is_not_silent(mode: str) -> None:
    """Each frame alone finds its place about one time in four: the sequence does, and the line says so."""
    rng = np.random.default_rng(6)
    places = np.arange(0, 300)
    sim = planted(rng, 400, places, 2.2)
    single = evaluate_mode(get_matcher("single"), sim, places[:, None], tolerance=0).recall[1]
    assert 0.15 <= single <= 0.45
    r = run(sim, places, mode=mode)
    assert r.recall[1] >= 0.9
    assert r.mapped_right >= 0.5 and r.answered_right >= 0.95


@pytest.mark.parametrize("mode", [*MODES, "stream"])
def test_foreign_imagery_is_lost(mode: str) -> None:
    """Frames of a place the map does not hold at all: similarities with no structure, nearly all lost."""
    rng = np.random.default_rng(7)
    places = -np.ones(400, int)
    r = run(planted(rng, 300, places, 0.0), places, mode=mode)
    assert r.lost_unmapped >= 0.99


@pytest.mark.parametrize("mode", [*MODES, "stream"])
def test_foreign_imagery_with_a_look_alike_is_lost(mode: str) -> None:
    """Imagery of somewhere else in which one reference looks most like every frame (a hub of that stream):
    no trajectory of it is this place."""
    rng = np.random.default_rng(9)
    places = -np.ones(200, int)
    sim = planted(rng, 300, places, 0.0)
    sim[:, 120] += 2.5   # the look-alike
    sim[:, 121] += 1.5
    assert run(sim, places, mode=mode).lost_unmapped >= 0.99


@pytest.mark.parametrize("rule, width, lift", [({"hub": 1.0, "stuck": 0}, 5, 3.0),
                                               ({"hub": -99.0, "stuck": 4}, 2, 5.0)])
def test_the_hub_line_and_the_stuck_rule_lose_more_of_a_look_alike(rule: dict, width: int, lift: float) -> None:
    """Imagery of somewhere else that resembles a stretch of ``width`` references by ``lift`` (a camera that
    moves, by its motion cue): ``stream``'s trajectories can creep along the stretch or sit on it; the hub line
    (the answer's view less its place's mean over the stream's recent frames; a stretch of five) and the stuck
    rule (the answer kept one place while the camera moved; two places, a sharper look-alike) each lose more of
    those frames than the same matcher without either, in every draw, and 0.05 more on average."""
    on, off = [], []
    for seed in range(6):
        rng = np.random.default_rng(seed)
        places = -np.ones(200, int)
        sim = planted(rng, 300, places, 0.0)
        sim[:, 120:120 + width] += lift
        m = get_matcher("stream")
        on.append(np.mean(m.with_params(**rule).run(sim, still=np.zeros(200)).scores < m.min_confidence))
        off.append(np.mean(m.with_params(hub=-99.0, stuck=0).run(sim, still=np.zeros(200)).scores
                           < m.min_confidence))
    assert all(a >= b for a, b in zip(on, off)) and np.mean(on) - np.mean(off) >= 0.05, (on, off)


def test_near_values_against_a_loop() -> None:
    rng = np.random.default_rng(7)
    values = rng.normal(size=80)
    near = [(3, 9), (40, 41), (70, 80)]
    places, got = near_values(values, None, near)
    want = [p for p in range(80) if any(lo <= p < hi for lo, hi in near)]
    assert places.tolist() == want and got.tolist() == values[want].tolist()
    where = np.sort(rng.choice(200, 80, replace=False))
    places, got = near_values(values, where, near)
    keep = [i for i, p in enumerate(where) if any(lo <= p < hi for lo, hi in near)]
    assert places.tolist() == where[keep].tolist() and got.tolist() == values[keep].tolist()


def test_place_probability_is_a_softmax_over_near_places_and_rivals() -> None:
    rng = np.random.default_rng(8)
    places = np.arange(20, 41)
    values = rng.uniform(0, 10, len(places))
    best = float(values.max())
    answer = int(places[np.argmax(values)])
    right = [(answer - 2, answer + 3)]
    rivals, scale = 0.7, 1.5
    weights = {int(p): np.exp((v - best) / scale) for p, v in zip(places, values)}
    want = sum(w for p, w in weights.items() if answer - 2 <= p <= answer + 2) / (sum(weights.values()) + rivals)
    assert place_probability(best, places, values, right, rivals, scale) == pytest.approx(want)
    # only the answer near: the trajectory's probability against the rivals
    alone = place_probability(best, np.array([answer]), np.array([best]), right, rivals, scale)
    assert alone == pytest.approx(trajectory_probability(rivals))
    assert place_probability(best, places, values, right, rivals, None) == 0.0


def test_expected_precision_and_the_line_score_against_loops() -> None:
    rng = np.random.default_rng(9)
    recent = rng.uniform(size=50)
    for p in (0.05, 0.5, 0.95, float(recent.max())):
        sure = [x for x in recent if x >= p]
        want = sum(sure) / len(sure)
        assert expected_precision(p, recent) == pytest.approx(want)
        assert line_score(p, recent, 0.9) == pytest.approx(want if p >= 0.9 else p)
    assert expected_precision(0.3, np.zeros(0)) == 0.3


def test_a_sure_stretch_does_not_carry_the_answers_of_a_place_off_the_map() -> None:
    """After a long stretch of sure answers the frames of an unmapped place are lost at once: the line's
    mean over answers "at least as sure" would still stand high, the floor does not let them through."""
    rng = np.random.default_rng(5)
    places = np.r_[np.arange(0, 120), -np.ones(30, int), np.arange(150, 250)]
    r = run(planted(rng, 260, places, 4.0), places)
    assert r.lost_unmapped >= 0.95 and r.exit_frames[0] <= 2
    p = r.probabilities
    carried = [i for i in np.flatnonzero(places < 0) if expected_precision(p[i], p[max(0, i - 499):i + 1]) >= 0.98]
    assert len(carried) > 2   # what the mean alone would have answered


@pytest.mark.parametrize("mode", MODES)
def test_foreign_imagery_after_a_firm_lock_is_lost(mode: str) -> None:
    """A long map followed under a firm lock (a local search: the decoy waits while its gate is open), then,
    the camera moving on, imagery of somewhere else in which the place just past the lock looks most like
    every frame: at least 95% of its frames are lost, the first within 3 frames of leaving."""
    from vpr_edge.matchers.base import step

    rng = np.random.default_rng(11)
    n = 1000
    places = np.r_[np.arange(100, 160), -np.ones(80, int)]
    sim = planted(rng, n, places, 4.0)
    sim[60:, 162] += 2.5   # the look-alike, just past where the mapped stretch ended
    sim[60:, 163] += 1.5
    m = get_matcher(mode).stream(n)
    local, scores = [], []
    for row in sim:
        local.append(m.wanted() is not None)
        scores.append(step(m, lambda idx, row=row: row if idx is None else row[idx], 0.1)[1])   # moving
    lost = np.asarray(scores) < 0.98
    assert all(local[30:61])   # a firm lock: the frames searched locally, the first foreign one too
    assert np.mean(~lost[20:60]) > 0.9
    assert np.mean(lost[60:]) >= 0.95 and lost[60:64].any()


def test_recent_views_correct_a_place_seen_by_every_frame_in_full() -> None:
    """A hub (the place every frame of the stream sees alike) is corrected to about 0 once seen often: the
    prior is weighed against every sighting, not the memory's weight, which would leave 1/(memory + 1) of it."""
    recent = RecentViews(3, memory=10.0, prior=1.0)
    for _ in range(60):
        views = recent.read(np.array([9.0, 0.0, 0.0]), slice(None), learn=True)
    assert abs(views[0]) < 9.0 / 50   # 9 * 1/61 left of it; the memory's weight alone leaves 9/11 = 0.82
    first = RecentViews(3, memory=10.0, prior=1.0).corrected(np.array([9.0, 0.0, 0.0]), slice(None))
    assert first[0] == 9.0   # nothing seen yet: the frame's own z-score
