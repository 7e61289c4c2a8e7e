"""The matcher registry and contract; SeqSLAM against plain loops; the road matcher and open-ends DTW on
planted routes (speeds 0-3, a detour, a restart)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from vpr_edge.evaluation.scoring import evaluate_mode
from vpr_edge.matchers import MATCHERS, get_matcher
from vpr_edge.matchers.contrast import local_contrast
from vpr_edge.matchers.base import step, stillness
from vpr_edge.matchers.road import RoadMatcher
from vpr_edge.matchers.seqslam import SeqSLAMOnline, enhanced_difference, seqslam_match, speeds


def naive_contrast(sim: np.ndarray, window: int) -> np.ndarray:
    out = np.empty_like(sim, dtype=float)
    r = sim.shape[1]
    for i in range(sim.shape[0]):
        for j in range(r):
            w = sim[i, max(0, j - window // 2): min(r, j + window // 2 + 1)]
            out[i, j] = (sim[i, j] - w.mean()) / np.sqrt(w.var() + 1e-12)
    return out


def naive_seqslam(sim, ds, vmin, vmax, r_window, match_window, online):
    d = -naive_contrast(sim, r_window)
    q, r = d.shape
    v = speeds(ds, vmin, vmax)
    refs, scores = [], []
    if not online:
        d = d - d.min()
    for n in range(q):
        values, pos = [], []
        for s in range(r):
            best, best_pos = np.inf, 0
            for vel in v:
                total = 0.0
                if online:
                    frames = range(max(0, n - ds), n + 1)
                    for x in frames:
                        row = d[x] - d[x].min()
                        total += row[max(s - int(np.floor((n - x) * vel + 1e-9)), 0)]
                    p = s
                else:
                    length = min(ds + 1, q)
                    x0 = min(max(n - ds // 2, 0), q - length)
                    for k in range(length):
                        total += d[x0 + k, min(s + int(np.floor(k * vel + 1e-9)), r - 1)]
                    p = min(s + int(np.floor((n - x0) * vel + 1e-9)), r - 1)
                if total < best:
                    best, best_pos = total, p
            values.append(best)
            pos.append(best_pos)
        values = np.array(values)
        s = int(np.argmin(values))
        far = np.abs(np.arange(r) - s) > match_window // 2
        refs.append(pos[s])
        scores.append(1 - values[s] / values[far].min())
    return np.array(refs), np.array(scores)


def planted(rng: np.random.Generator, n_refs: int, places: np.ndarray, noise: float = 0.35) -> np.ndarray:
    """Similarity rows (F, R) for a vehicle at ``places`` (-1 = off the map): a bump at the true place over
    smooth noise, as cosine similarities of encodings behave."""
    sim = noise * rng.normal(size=(len(places), n_refs))
    on = places >= 0
    sim[np.flatnonzero(on), places[on]] += 1.0
    return sim


def test_local_contrast_matches_loop() -> None:
    sim = np.random.default_rng(0).normal(size=(4, 23))
    for w in (2, 5, 10):
        np.testing.assert_allclose(local_contrast(sim, w), naive_contrast(sim, w), atol=1e-9)


@pytest.mark.parametrize("online", [False, True])
def test_seqslam_matches_plain_loops(online: bool) -> None:
    rng = np.random.default_rng(1)
    places = np.clip(np.round(np.cumsum(rng.uniform(0.5, 2.0, 16))).astype(int), 0, 39)
    sim = planted(rng, 40, places, noise=0.3)
    params = {"ds": 4, "vmin": 0.5, "vmax": 2.0, "r_window": 6, "match_window": 6}
    want_refs, want_scores = naive_seqslam(sim, online=online, **params)
    if online:
        m = SeqSLAMOnline(40, **params)
        got = np.array([m.update(row) for row in sim])
        got_refs, got_scores = got[:, 0].astype(int), got[:, 1]
    else:
        res = seqslam_match(sim, **params)
        got_refs, got_scores = res.refs, res.scores
    np.testing.assert_array_equal(got_refs, want_refs)
    np.testing.assert_allclose(got_scores, want_scores, atol=1e-9)
    assert np.mean(np.abs(got_refs - places) <= 1) > 0.7


def test_seqslam_difference_is_non_negative() -> None:
    d = enhanced_difference(np.random.default_rng(2).normal(size=(5, 30)))
    assert d.min() == 0.0


def stop_cues(places: np.ndarray, moving: float = 0.5) -> np.ndarray:
    """A motion cue per frame of a planted route: 1.0 where the frame repeats the place before (the camera
    stands), ``moving`` elsewhere."""
    return np.where(np.r_[False, places[1:] == places[:-1]], 1.0, moving)


def route(speed_runs: list[tuple[float, int]], start: float = 0.0) -> np.ndarray:
    pos, out = start, []
    for speed, frames in speed_runs:
        for _ in range(frames):
            out.append(int(pos))
            pos += speed
    return np.array(out)


@pytest.mark.parametrize("speed", [0.0, 0.5, 1.0, 2.0, 3.0])
def test_road_matcher_follows_any_speed(speed: float) -> None:
    rng = np.random.default_rng(int(speed * 10))
    places = route([(1.0, 15), (speed, 60)], start=100)
    sim = planted(rng, 600, places)
    res = get_matcher("stream").run(sim)
    settled = slice(25, None)
    assert np.mean(np.abs(res.refs[settled] - places[settled]) <= 1) > 0.95


def test_road_matcher_stop_off_the_map_on_a_look_alike() -> None:
    """A vehicle that drives off the map and stops where the view resembles place 300 as a true match would
    (the frame repeated with fresh noise, as a camera repeats a view) stays lost; counting every repeat in full
    (stop_gain 1, the moving decay) locks on the look-alike. Eight noise draws, the shares over all of them."""
    default = get_matcher("stream")
    counted = replace(default, params={**default.params, "stop_gain": 1.0, "stop_decay": default.params["decay"]})
    places = np.concatenate([route([(1.0, 40)], start=50), np.full(10, -1), np.full(12, 300)])
    stop = slice(54, 62)
    lost, parked = [], []
    for seed in range(8):
        sim = planted(np.random.default_rng(seed), 600, places)
        res, old = default.run(sim), counted.run(sim)
        assert np.mean(np.abs(res.refs[10:40] - places[10:40]) <= 1) > 0.95
        lost.append(np.mean(res.scores[stop] < default.min_confidence))
        parked.append(np.mean((old.refs[stop] == 300) & (old.scores[stop] >= counted.min_confidence)))
    assert np.mean(lost) > 0.8 and np.mean(parked) > 0.6


def test_road_matcher_lag_trap_and_stop_on_a_mapped_place() -> None:
    """A look-alike stretch that a slower trajectory fits (places 100, 100, 101, 101, ... while the vehicle
    runs 100, 101, 102, ... at speed 1), 0.6 as strong as the true match: the answer follows the vehicle, never
    a confident wrong one. (At 0.8 it is not so yet: 25 confident wrong frames over these 8 draws, 194 at equal
    strength; docs/results.md, "Right or silent".) A stop of 30 frames on a mapped place (its view repeated with fresh noise): the
    vehicle stays localised through it. Eight noise draws each."""
    matcher = get_matcher("stream")
    for seed in range(8):
        rng = np.random.default_rng(seed)
        places = route([(1.0, 160)], start=20)
        sim = planted(rng, 400, places)
        trap = np.arange(80, 141)                          # the vehicle at places 100 ... 160
        sim[trap, 100 + (trap - 80) // 2] += 0.6           # the slower look-alike, 0.6 of a true match
        res = matcher.run(sim)
        confident_wrong = (np.abs(res.refs - places) > 2) & (res.scores >= matcher.min_confidence)
        assert not confident_wrong[20:].any(), np.flatnonzero(confident_wrong)
        stopped = np.concatenate([route([(1.0, 80)], start=20), np.full(30, 100), route([(1.0, 60)], start=101)])
        res = matcher.run(planted(rng, 400, stopped))
        stop = slice(80, 110)
        assert np.all(res.scores[stop] >= matcher.min_confidence) and np.all(np.abs(res.refs[stop] - 100) <= 1)


def test_road_matcher_detour_lost_and_restart() -> None:
    rng = np.random.default_rng(9)
    places = np.concatenate([route([(1.0, 40), (2.0, 30)], start=50), np.full(40, -1),
                             route([(1.5, 40)], start=400)])
    sim = planted(rng, 600, places)
    matcher = get_matcher("stream")
    res = matcher.run(sim)
    first, second, off = slice(10, 70), slice(125, 150), slice(80, 110)
    assert np.mean(np.abs(res.refs[first] - places[first]) <= 1) > 0.95
    assert np.mean(np.abs(res.refs[second] - places[second]) <= 1) > 0.95      # re-locked elsewhere
    assert np.mean(res.scores[off] < matcher.min_confidence) > 0.9              # lost while off the map
    assert np.mean(res.scores[first] < matcher.min_confidence) < 0.05
    # reset forgets: a fresh start at another place locks on as quickly as the first time
    online = matcher.stream(600)
    for row in sim[:60]:
        online.update(row)
    online.reset()
    again = [online.update(row)[0] for row in sim[125:]]
    assert np.mean(np.abs(np.array(again[10:]) - places[135:]) <= 1) > 0.95


def test_road_matcher_detour_through_look_alikes() -> None:
    """Off the map the view may resemble mapped places: here every detour frame resembles some mapped place
    as strongly as a true match (strength 1.0, each frame another place) or in short runs that follow the
    route for three frames at 0.8 of a true match. No such run is a trajectory, so once the lock's evidence
    has faded (its memory: 8-12 frames, docs/results.md, "Right or silent") the frames are reported lost, and
    the vehicle is found again within a few frames of re-entering the map. Eight noise draws each."""
    matcher = get_matcher("stream")
    for strength, run in ((1.0, 1), (0.8, 3)):
        lost, found = [], []
        for seed in range(8):
            rng = np.random.default_rng(seed)
            places = np.concatenate([route([(1.0, 60)], start=50), np.full(40, -1), route([(1.0, 60)], start=300)])
            sim = planted(rng, 600, places)
            off = np.flatnonzero(places < 0)
            for k in range(0, len(off), run):      # each run of look-alikes follows another stretch of the map
                start = int(rng.integers(0, 600 - run))
                sim[off[k:k + run], start + np.arange(len(off[k:k + run]))] += strength
            res = matcher.run(sim)
            lost.append(np.mean(res.scores[off[13:]] < matcher.min_confidence))
            back = slice(off[-1] + 1, None)
            ok = (np.abs(res.refs[back] - places[back]) <= 2) & (res.scores[back] >= matcher.min_confidence)
            found.append(int(np.argmax(ok)) if ok.any() else len(ok))
        assert np.mean(lost) > 0.9 and min(lost) > 0.8, (strength, run, lost)
        assert max(found) <= 6, (strength, run, found)


def test_evaluate_reports_lock_on_and_exit_delays() -> None:
    """evaluate's lock / exit figures on the planted detour: the stream locks on within a few frames at the
    start and after re-entering, and reports lost within about 1 / (1 - decay) frames of leaving (its evidence
    fades, it does not vanish); a matcher without a lost state has no exit figure."""
    rng = np.random.default_rng(9)
    places = np.concatenate([route([(1.0, 40), (2.0, 30)], start=50), np.full(40, -1),
                             route([(1.5, 40)], start=400)])
    truth = places[:, None]
    sim = planted(rng, 600, places)
    stream = evaluate_mode(get_matcher("stream"), sim, truth)
    assert len(stream.lock_frames) == 2 and max(stream.lock_frames) <= 8
    assert len(stream.exit_frames) == 1 and stream.exit_frames[0] <= 12
    single = evaluate_mode(get_matcher("single"), sim, truth)
    assert single.exit_frames == () and len(single.lock_frames) == 2


def naive_road(sim, vmax, grid, decay, bias, turn, memory, lock, rival_window, stop_gain, stop_decay, still=0.0,
               cues=None):
    """RoadMatcher written as plain loops over states, from its docstring (``cues``: each frame's motion cue,
    NaN = none)."""
    n_refs = sim.shape[1]
    n_speeds, n_pos = int(round(vmax * grid)) + 1, n_refs * grid
    h = np.zeros((n_speeds, n_pos))
    mean, weight, stopped, out = np.zeros(n_refs), memory, False, []
    for t, s in enumerate(sim):
        cue = np.nan if cues is None else cues[t]
        gain, s_decay, stands = stop_gain, stop_decay, False   # no cue: the stop_gain rule
        if still > 0 and cue == cue:
            gain, s_decay, stands = 0.0, decay, cue >= still
        if not stands:   # a standing camera's frame leaves the state (and the hub means) as they were
            z = (s - s.mean()) / s.std()
            zr = z - mean
            if not stopped:
                weight = (1 - 1 / memory) * weight + 1
                mean = mean + (z - mean) / weight
            new = np.zeros_like(h)
            for v in range(n_speeds):
                for p in range(n_pos):
                    prev = max((h[u, p - v] - turn * abs(v - u) for u in range(n_speeds)),
                               default=0.0) if p >= v else 0.0
                    e = zr[p // grid] - bias
                    if v == 0:   # speed 0: decays by s_decay, a positive excess counts gain of itself
                        new[v, p] = max(0.0, max(0.0, s_decay * prev) + (gain * e if e > 0 else e))
                    else:
                        new[v, p] = max(0.0, max(0.0, decay * prev) + e)
            h = new
        v_best, p_best = np.unravel_index(np.argmax(h), h.shape)
        stopped, ref, best = v_best == 0, p_best // grid, h[v_best, p_best]
        rival = max([h[:, p].max() for p in range(n_pos) if abs(p // grid - ref) > rival_window], default=0.0)
        out.append((ref, float(best >= lock) + 1 - (rival + 1) / (best + 1)))
    return out


@pytest.mark.parametrize("grid, vmax, stop_gain, stop_decay", [(1, 2.0, 0.3, 0.95), (2, 1.5, 0.3, 0.95),
                                                                (2, 1.5, 1.0, 0.8)])
def test_road_matcher_against_plain_loops(grid: int, vmax: float, stop_gain: float, stop_decay: float) -> None:
    rng = np.random.default_rng(grid)
    sim = planted(rng, 20, route([(1.0, 12), (0.0, 5), (0.5, 8)], start=1), noise=0.6)
    params = {"vmax": vmax, "grid": grid, "decay": 0.8, "bias": 0.5, "turn": 0.7, "memory": 6.0, "lock": 3.0,
              "rival_window": 2, "stop_gain": stop_gain, "stop_decay": stop_decay}
    m = RoadMatcher(20, **MATCHERS["stream"].params | params)
    got = [m.update(row) for row in sim]
    want = naive_road(sim, **params)
    assert [r for r, _ in got] == [r for r, _ in want]
    np.testing.assert_allclose([c for _, c in got], [c for _, c in want], atol=1e-5)   # float32 state
    assert any(c >= 1 for _, c in got) and any(c < 1 for _, c in got)   # both locked and unlocked frames


def test_road_matcher_motion_cue_against_plain_loops() -> None:
    """Frames with a cue at or above ``still`` (a stop), below it (motion) and without one (NaN: the stop_gain
    rule), against the loops; the cue changes the answers' scores."""
    rng = np.random.default_rng(5)
    places = route([(1.0, 10), (0.0, 8), (1.0, 6), (0.5, 6)], start=1)
    sim = planted(rng, 20, places, noise=0.6)
    cues = stop_cues(places, 0.4)
    cues[[0, 15, 16]] = np.nan
    params = {"vmax": 1.5, "grid": 2, "decay": 0.8, "bias": 0.5, "turn": 0.7, "memory": 6.0, "lock": 3.0,
              "rival_window": 2, "stop_gain": 0.3, "stop_decay": 0.95, "still": 0.99}
    got = MATCHERS["stream"].with_params(**params).run(sim, k=1, still=cues)
    want = naive_road(sim, **params, cues=cues)
    assert list(got.refs) == [r for r, _ in want]
    np.testing.assert_allclose(got.scores, [c for _, c in want], atol=1e-5)
    blind = naive_road(sim, **params)
    assert not np.allclose([c for _, c in want], [c for _, c in blind], atol=1e-3)
    off = MATCHERS["stream"].with_params(**params | {"still": 0.0}).run(sim, k=1, still=cues)   # 0: cue unused
    np.testing.assert_allclose(off.scores, [c for _, c in blind], atol=1e-5)


def test_stillness_against_a_loop() -> None:
    enc = np.random.default_rng(0).normal(size=(6, 5))
    enc[3] = 2.5 * enc[2]          # the same view again (scale does not matter)
    enc[5] = 0.0                   # no direction: no cue
    got = stillness(enc)
    assert np.isnan(got[0]) and np.isnan(got[5]) and got[3] == pytest.approx(1.0)
    for i in (1, 2, 4):
        a, b = enc[i], enc[i - 1]
        assert got[i] == pytest.approx(a @ b / np.linalg.norm(a) / np.linalg.norm(b))


def test_anchored_stillness_against_a_loop() -> None:
    """With a threshold, each frame is compared with the last frame whose cue fell below it (the anchor); a
    camera creeping by steps of cosine 0.995 (each 0.1 rad on to the previous frame) shows motion every other
    frame against the anchor, where frame-to-frame it would look standing forever."""
    rng = np.random.default_rng(1)
    enc = rng.normal(size=(12, 6))
    enc[[4, 5, 6]] = enc[3] + 1e-4 * rng.normal(size=(3, 6))   # standing
    enc[9] = 0.0                                               # no cue; becomes the anchor
    got = stillness(enc, 0.99)
    anchor, want = 0, [np.nan]
    for t in range(1, len(enc)):
        na, nt = np.linalg.norm(enc[anchor]), np.linalg.norm(enc[t])
        want.append(enc[t] @ enc[anchor] / (na * nt) if na > 0 and nt > 0 else np.nan)
        if not (want[-1] >= 0.99):
            anchor = t
    np.testing.assert_allclose(got, want, equal_nan=True)
    assert np.isnan(got[10]) and (got[[4, 5, 6]] > 0.99).all()
    theta = 0.1 * np.arange(20)
    creep = np.c_[np.cos(theta), np.sin(theta), np.zeros((20, 3))]
    assert (stillness(creep)[1:] > 0.99).all()                      # frame to frame: always standing
    moving = stillness(creep, 0.99)[1:] < 0.99
    assert moving[1::2].all() and not moving[0::2].any()            # against the anchor: every other frame


def test_road_matcher_follows_a_creep_with_the_anchored_cue() -> None:
    """A vehicle creeping at a quarter place a frame whose frames each differ from the one before by less
    than the standing threshold: with the cue against the last frame that moved it is followed; with a
    frame-to-frame cue every frame would read as standing, the state would freeze and the answer stay
    where the creep began."""
    matcher = get_matcher("stream")
    places = np.concatenate([route([(1.0, 40)], start=50), route([(0.25, 120)], start=90)])
    theta = np.r_[np.arange(40) * 2.0, 80 + 0.1 * np.arange(120)]       # moving: unrelated views; creeping: 0.1 rad a frame
    enc = np.c_[np.cos(theta), np.sin(theta), np.zeros((160, 3))]
    enc[:40, 2:] = np.random.default_rng(0).normal(size=(40, 3))
    for seed in range(4):
        sim = planted(np.random.default_rng(seed), 400, places)
        follows = matcher.run(sim, still=matcher.cue(enc))
        frozen = matcher.run(sim, still=stillness(enc))
        late = slice(100, None)
        assert np.mean(np.abs(follows.refs[late] - places[late]) <= 2) > 0.9
        assert np.mean(np.abs(frozen.refs[late] - places[late]) <= 2) < 0.2


def test_road_matcher_long_stop_held_with_the_motion_cue() -> None:
    """A stop of 120 frames on a mapped place, its view repeated with fresh noise: with the motion cue (the
    camera is seen to stand: its frames leave the state as it was) every stopped frame stays locked within 2
    places of the stop over eight noise draws; without it (the stop_gain rule alone) the lock fades in most
    draws."""
    matcher = get_matcher("stream")
    held, held_blind = 0, 0
    for seed in range(8):
        rng = np.random.default_rng(seed)
        places = np.concatenate([route([(1.0, 80)], start=20), np.full(120, 100), route([(1.0, 60)], start=101)])
        sim = planted(rng, 400, places)
        cues = stop_cues(places)
        stop = slice(80, 200)
        for res, n in ((matcher.run(sim, still=cues), 0), (matcher.run(sim), 1)):
            ok = bool(np.all(res.scores[stop] >= matcher.min_confidence) and np.all(np.abs(res.refs[stop] - 100) <= 2))
            held, held_blind = (held + ok, held_blind) if n == 0 else (held, held_blind + ok)
    assert held == 8 and held_blind <= 2, (held, held_blind)


def test_road_matcher_stop_not_overrun_with_the_motion_cue() -> None:
    """A vehicle stops at place 100 where the next places look alike (in a corridor the view from one door
    resembles the next three): each stopped frame's row also has 0.8 of a true match at 101-103. The moving
    trajectory could feed on them and run past the stop; with the motion cue a standing camera's view feeds no
    moving trajectory, so every stopped frame is answered within one place of the stop. Eight noise draws."""
    matcher = get_matcher("stream")
    for seed in range(8):
        rng = np.random.default_rng(seed)
        places = np.concatenate([route([(1.0, 60)], start=40), np.full(25, 100), route([(1.0, 40)], start=101)])
        sim = planted(rng, 400, places)
        stop = np.flatnonzero(places == 100)[1:]               # the frames that repeat the view
        sim[stop[:, None], np.arange(101, 104)[None]] += 0.8
        cues = stop_cues(places)
        res = matcher.run(sim, still=cues)
        assert np.all(np.abs(res.refs[stop] - 100) <= 1), (seed, res.refs[stop])
        assert np.all(res.scores[stop] >= matcher.min_confidence)


def test_road_matcher_off_map_stop_with_the_motion_cue_stays_lost() -> None:
    """Off the map for 10 moving frames, then stopped for 30 frames where the view resembles place 300 as a
    true match would: with the cue saying moving, then stopped, the repeated view builds no lock (a stop holds
    a lock, it does not make one): lost through at least 90% of the stop over eight draws, locked on 300 in
    at most 10% (counting each repeat in full instead locks on it in 85%)."""
    matcher = get_matcher("stream")
    places = np.concatenate([route([(1.0, 40)], start=50), np.full(10, -1), np.full(30, 300)])
    cues = np.full(len(places), 0.5)
    cues[51:] = 1.0
    stop = slice(50, 80)
    lost, parked = [], []
    for seed in range(8):
        res = matcher.run(planted(np.random.default_rng(seed), 600, places), still=cues)
        lost.append(np.mean(res.scores[stop] < matcher.min_confidence))
        parked.append(np.mean((res.refs[stop] == 300) & (res.scores[stop] >= matcher.min_confidence)))
    assert np.mean(lost) >= 0.9 and np.mean(parked) <= 0.1, (np.mean(lost), np.mean(parked))


@pytest.mark.parametrize("n_refs", [2, 3, 4])
def test_road_matcher_route_shorter_than_its_fastest_step(n_refs: int) -> None:
    """Maps with fewer positions than the top speed's step (4 places/frame x grid 2) run, as the loops do; a
    one-place map answers that place and never locks (a z-score over one reference is 0)."""
    one = get_matcher("stream").run(np.random.default_rng(0).normal(size=(8, 1)))
    assert (one.refs == 0).all() and (one.scores < 1).all()
    sim = np.random.default_rng(n_refs).normal(size=(8, n_refs))
    sim[:, 0] += 1e-3   # no row is constant (its z-score would be 0/0)
    params = dict(MATCHERS["stream"].params)
    params = {k: params[k] for k in ("vmax", "grid", "decay", "bias", "turn", "memory", "lock", "rival_window",
                                     "stop_gain", "stop_decay")} | {"bias": 0.5, "lock": 1.0}  # no all-0 states
    m = RoadMatcher(n_refs, **MATCHERS["stream"].params | params)
    got = [m.update(row) for row in sim]
    want = naive_road(sim, **params)
    assert [r for r, _ in got] == [r for r, _ in want]
    np.testing.assert_allclose([c for _, c in got], [c for _, c in want], atol=1e-5)


def test_road_matcher_state_is_bounded() -> None:
    m = RoadMatcher(50, **MATCHERS["stream"].params)
    rng = np.random.default_rng(0)
    before = m.h.nbytes
    for _ in range(300):
        m.update(rng.normal(size=50))
    assert m.h.nbytes == before == 9 * 2 * 50 * 4          # float32 (speeds x positions)
    with pytest.raises(ValueError):
        m.update(np.zeros(49))


def test_remove_hubs_against_plain_loops() -> None:
    from vpr_edge.matchers.dtw import remove_hubs

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
    places = route([(1.0, 30), (2.0, 30)], start=40)
    sim = planted(rng, 200, places, noise=0.3)
    sim[:, 5] += 1.3
    res = get_matcher("dtw-open").run(sim)
    assert np.mean(np.abs(res.refs - places) <= 1) > 0.9
    parked = get_matcher("dtw-open").with_params(hubs=False).run(sim)
    assert np.mean(parked.refs == 5) > 0.9


@pytest.mark.parametrize("speed", [2.0, 3.0])
def test_open_ends_dtw_follows_fast_vehicle(speed: float) -> None:
    rng = np.random.default_rng(int(speed))
    places = route([(speed, 40)], start=60)
    sim = planted(rng, 400, places, noise=0.5)
    res = get_matcher("dtw-open").run(sim)
    assert np.mean(np.abs(res.refs - places) <= 1) >= 0.85     # the first frames fix the start
    fixed = get_matcher("dtw").run(sim)
    assert np.mean(np.abs(fixed.refs - places) <= 1) < 0.5     # fixed ends cannot: the route is partial


@pytest.mark.parametrize("name", list(MATCHERS))
def test_every_matcher_keeps_the_contract(name: str) -> None:
    rng = np.random.default_rng(4)
    places = route([(1.0, 30)], start=0)
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


def test_local_search_follows_a_long_route_and_finds_a_jump() -> None:
    """On a large route the stream matcher searches a window around a firm lock (``wanted``), checks the
    whole route now and then, and re-locks after the vehicle turns up far away (a kidnap)."""
    rng = np.random.default_rng(4)
    places = np.concatenate([route([(1.0, 60), (3.0, 40), (0.0, 20), (0.5, 40)], start=100),
                             route([(2.0, 120)], start=2200)])
    sim = planted(rng, 3000, places, noise=0.3)
    matcher = get_matcher("stream").with_params(window=50)
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
    m = RoadMatcher(400, **MATCHERS["stream"].params | {"window": 100})
    for row in planted(np.random.default_rng(0), 400, np.arange(100, 150)):
        m.update(row)
        assert m.wanted() is None
    with pytest.raises(ValueError):
        RoadMatcher(3000, **MATCHERS["stream"].params | {"window": 50}).update(np.zeros(10), np.arange(10))   # refs not asked for


def test_parse_params_reads_each_default_type_and_refuses_bad_items() -> None:
    stream, dtw = get_matcher("stream"), get_matcher("dtw-open")
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


def test_road_matcher_takes_whole_numbers_for_real_parameters() -> None:
    """From Python a real-valued parameter may come as an int (``params={"memory": 25}``): the matcher runs as
    with the same float (it once kept an int64 array for the running means and failed on the first frame)."""
    sim = planted(np.random.default_rng(4), 60, route([(1.0, 30)], start=5))
    floats = {k: v for k, v in get_matcher("stream").params.items() if isinstance(v, float) and v == int(v)}
    assert "memory" in floats
    as_ints = get_matcher("stream").with_params(**{k: int(v) for k, v in floats.items()})
    np.testing.assert_array_equal(as_ints.run(sim).refs, get_matcher("stream").run(sim).refs)
