"""The motion cue (``matchers.motion``: does the camera stand?) against a loop, on two cameras, and the road
(``stream``) matcher reading it: stops held, not overrun, a creep followed, the map's own stops moved through."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from helpers import exposures, naive_road, places_at_speeds, planted, stop_cues, unit_rows
from vpr_edge.matchers import MATCHERS, get_matcher
from vpr_edge.matchers.constants import MEMORY, MIN_STEPS, REPEAT_STEP
from vpr_edge.matchers.motion import route_stands, stillness


def naive_cue(enc: np.ndarray, threshold: float | None, memory: int = MEMORY) -> list[float]:
    """The motion cue as plain loops, from ``motion``'s docstring: 1 - (1 - cosine to the anchor) / the
    median step of the last ``memory`` moving frames (until MIN_STEPS of them, those frames move with cue 0); the
    anchor's encoding again (a duplicated frame): cue 1, no step."""
    anchor, steps, out = None, [], []
    for e in enc:
        if anchor is None or not np.linalg.norm(e) or not np.linalg.norm(anchor):
            anchor = e
            out.append(np.nan)
            continue
        d = 1 - e @ anchor / (np.linalg.norm(e) * np.linalg.norm(anchor))
        if d <= REPEAT_STEP:   # the anchor again, bit for bit: the same view, no step
            out.append(1.0)
            if threshold is None:
                anchor = e
            continue
        typical = np.median(steps[-memory:]) if len(steps) >= min(MIN_STEPS, memory) else None
        out.append(0.0 if typical is None else 1 - d / typical)
        if threshold is None or not out[-1] >= threshold:
            anchor = e
            steps.append(d)
    return out


@pytest.mark.parametrize("threshold, memory", [(None, 30), (0.5, 30), (0.5, 4), (0.8, 2)])
def test_stillness_against_a_loop(threshold: float | None, memory: int) -> None:
    """Random frames, standing stretches (the same view with a little noise), a rescaled repeat (scale does not
    matter), an all-zero frame (no cue; it becomes the anchor): the cue as the loops compute it."""
    rng = np.random.default_rng(0)
    enc = rng.normal(size=(40, 6))
    enc[[8, 9, 10]] = enc[7] + 0.05 * rng.normal(size=(3, 6))
    enc[20] = 2.5 * enc[19]
    enc[25] = 0.0
    enc[30:36] = enc[29] + 0.1 * rng.normal(size=(6, 6))
    got = stillness(enc, threshold, memory)
    np.testing.assert_allclose(got, naive_cue(enc, threshold, memory), equal_nan=True)
    assert np.isnan(got[0]) and np.isnan(got[25]) and np.isnan(got[26]) and got[20] == pytest.approx(1.0)
    assert (got[[8, 9, 10]] > 0.5).all() and (got[[1, 2, 3]] < 0.5).all()
    if threshold is not None:   # along a map, in blocks: the same decisions
        want = np.nan_to_num(got, nan=-np.inf) >= threshold
        for cuts in ([40], [9, 26, 31], [1] * 40):
            blocks = np.split(enc, np.cumsum(cuts)[:-1])
            np.testing.assert_array_equal(route_stands(blocks, threshold, memory), want)



def test_a_duplicated_frame_is_the_same_view_from_the_first():
    """A stream that starts with its first frame repeated bit for bit (a video that waits, frames copied): the
    copies read as the same view (cue 1) from the start, and add no step, so the first moving frames read as
    moving (near 0), not as a hundred million typical steps of nothing."""
    rng = np.random.default_rng(2)
    enc = rng.normal(size=(12, 8))
    enc[1:5] = enc[0]
    got = stillness(enc, 0.5)
    assert (got[1:5] == 1.0).all()
    assert (np.abs(got[5:8]) < 1.0).all() and (got[5:] < 0.5).all()


def test_narrow_band_front_end_moves_and_stands() -> None:
    """A front end whose cosines all lie in 0.999-1.0 (a network with random weights sees every image alike):
    moving frames 0.9995 alike, stops 0.99999. Read on its own scale from its first moving frames, every stop
    stands and every moving frame moves, along a map and in a stream; a fixed first step in cosine units (0.02,
    as once) read the whole stream as standing, so a matcher never moved."""
    rng = np.random.default_rng(11)

    def walk(n: int, angle: float, stop_angle: float, stops: bool) -> tuple[np.ndarray, np.ndarray]:
        frames, standing = [], []
        view = rng.normal(size=32)
        view /= np.linalg.norm(view)
        for t in range(n):
            stop = stops and t % 30 >= 22
            turn = rng.normal(size=32)
            turn -= (turn @ view) * view
            turn /= np.linalg.norm(turn)
            if stop:
                frames.append(np.cos(stop_angle) * view + np.sin(stop_angle) * turn)
            else:
                view = np.cos(angle) * view + np.sin(angle) * turn
                frames.append(view)
            standing.append(stop)
        return np.array(frames), np.array(standing)

    refs, _ = walk(100, np.arccos(0.9995), 0.0, False)
    assert not route_stands([refs[:40], refs[40:]], 0.5).any()
    enc, standing = walk(150, np.arccos(0.9995), np.arccos(0.99999), True)
    cue = stillness(enc, 0.5)
    assert (cue[1:1 + MIN_STEPS] == 0.0).all()      # the first moving frames set the scale
    settled = np.arange(len(enc)) >= 1 + MIN_STEPS
    assert (cue[standing & settled] >= 0.5).all() and (cue[~standing & settled] < 0.5).all()


def test_motion_cue_sets_its_threshold_from_the_stream() -> None:
    """Two cameras: one whose moving frames all differ (cosine ~0.5 between consecutive frames) and whose
    stops are new exposures of cosine ~0.85 to the last moving frame; one whose moving frames are all alike
    (cosine ~0.98, a slow camera or a featureless road) and whose stops are 0.997 alike. No fixed cosine
    tells both: 0.85 is motion on the second camera's scale and a stop on the first's. The relative cue
    reads every stop as standing and every moving frame as moving on both."""
    rng = np.random.default_rng(3)

    def camera(angle: float, stop: float) -> tuple[np.ndarray, np.ndarray]:
        """A random walk on the sphere with ``angle`` between moving frames, stopped for 10 frames every
        30 with new exposures at angle ``stop`` from the stop's view."""
        frames, standing, view = [], [], rng.normal(size=64)
        for t in range(200):
            if t % 30 >= 20:
                noise = rng.normal(size=64)
                noise -= (noise @ view) / (view @ view) * view
                frames.append(np.cos(stop) * view / np.linalg.norm(view) + np.sin(stop) * noise / np.linalg.norm(noise))
                standing.append(True)
                continue
            turn = rng.normal(size=64)
            turn -= (turn @ view) / (view @ view) * view
            view = np.cos(angle) * view / np.linalg.norm(view) + np.sin(angle) * turn / np.linalg.norm(turn)
            frames.append(view)
            standing.append(False)
        return np.array(frames), np.array(standing)

    for angle, stop in ((np.arccos(0.5), np.arccos(0.85)), (np.arccos(0.98), np.arccos(0.997))):
        enc, standing = camera(angle, stop)
        cue = stillness(enc, 0.5)
        settled = np.arange(len(enc)) >= 30            # after the first moving frames set the typical step
        assert (cue[standing & settled] >= 0.5).all() and (cue[~standing & settled] < 0.5).all(), angle
    raw = np.array([np.cos(np.arccos(0.85)), 0.98])    # the first camera's stop, the second camera's motion
    assert raw[0] < raw[1]                             # a fixed cosine threshold gets one of them wrong


def test_road_matcher_motion_cue_against_plain_loops() -> None:
    """Frames with a cue at or above ``still`` (a stop), below it (motion) and without one (NaN: the stop_gain
    rule), against the loops; the cue changes the answers' scores."""
    rng = np.random.default_rng(5)
    places = places_at_speeds([(1.0, 10), (0.0, 8), (1.0, 6), (0.5, 6)], start=1)
    sim = planted(rng, 20, places, noise=0.6)
    cues = stop_cues(places, 0.4)
    cues[[0, 15, 16]] = np.nan
    params = {"vmax": 1.5, "grid": 2, "decay": 0.8, "bias": 0.5, "turn": 0.7, "memory": 6.0, "lock": 3.0,
              "rival_window": 2, "stop_gain": 0.3, "stop_decay": 0.95, "still": 0.5}
    got = MATCHERS["stream-rules"].with_params(**params).run(sim, k=1, still=cues)
    want = naive_road(sim, **params, cues=cues)
    assert list(got.refs) == [r for r, _ in want]
    np.testing.assert_allclose(got.scores, [c for _, c in want], atol=1e-5)
    blind = naive_road(sim, **params)
    assert not np.allclose([c for _, c in want], [c for _, c in blind], atol=1e-3)
    off = MATCHERS["stream-rules"].with_params(**params | {"still": 0.0}).run(sim, k=1, still=cues)   # 0: cue unused
    np.testing.assert_allclose(off.scores, [c for _, c in blind], atol=1e-5)
    stood = np.zeros(20, bool)
    stood[11:15] = True                                   # the map's drive stood where the stop happens
    on_route = replace(MATCHERS["stream-rules"].with_params(**params), route=stood).run(sim, k=1, still=cues)
    want = naive_road(sim, **params, cues=cues, route=stood)
    assert list(on_route.refs) == [r for r, _ in want]
    np.testing.assert_allclose(on_route.scores, [c for _, c in want], atol=1e-5)


def test_road_matcher_holds_a_real_cameras_stop() -> None:
    """A camera stops for 40 frames at place 100; each stopped frame is a new exposure whose encoding is only
    0.8 alike the view (sensor noise on a small image), which no fixed cosine near 1 reads as a stop, while
    moving frames are unrelated views. The relative cue reads the stop, and every stopped frame is answered
    within 2 places of 100 and locked, over eight draws."""
    matcher = get_matcher("stream-rules")
    for seed in range(8):
        rng = np.random.default_rng(seed)
        places = np.concatenate([places_at_speeds([(1.0, 60)], start=40), np.full(40, 100), places_at_speeds([(1.0, 40)], start=101)])
        views = unit_rows(rng.normal(size=(400, 64)))
        enc = views[places]
        stop = np.flatnonzero(places == 100)[1:]
        enc[stop] = exposures(rng, views[np.full(len(stop), 100)], 0.8)
        cue = matcher.cue(enc)
        assert (cue[stop] >= matcher.still_threshold).all()
        res = matcher.run(planted(rng, 400, places), still=cue)
        assert np.all(np.abs(res.refs[stop] - 100) <= 2) and np.all(res.scores[stop] >= matcher.min_confidence)


def test_road_matcher_moves_through_the_maps_own_stop() -> None:
    """The mapping drive stood at a station (references 100-111 show one view, each a new exposure) and so
    did the vehicle, frame for frame (a frame-synchronised pair, as the shared datasets are): the map's stop
    is read from its references (``route_stands``), and the answer moves through it with the frames as the
    references did (every answer inside the station and moving on through it, the
    places after it followed), where reading the frames as a stop against an unknown route keeps the answer
    at the station's first references."""
    matcher = get_matcher("stream-rules")
    for seed in range(4):
        rng = np.random.default_rng(seed)
        views = unit_rows(rng.normal(size=(300, 64)))
        refs = views.copy()
        refs[101:112] = exposures(rng, views[np.full(11, 100)], 0.8)
        stood = route_stands([refs[:150], refs[150:]], matcher.still_threshold)
        assert stood[101:112].all() and stood.sum() == 11
        places = np.arange(60, 160)
        enc = views[places]
        enc[41:52] = exposures(rng, views[np.full(11, 100)], 0.8)      # frames of places 101-111
        sim = 0.35 * rng.normal(size=(len(places), 300)) + unit_rows(enc) @ refs.T
        cue = matcher.cue(enc)
        along = matcher.on_route([refs]).run(sim, still=cue)
        blind = matcher.run(sim, still=cue)
        station = slice(41, 52)
        assert np.all((along.refs[station] >= 100) & (along.refs[station] <= 112)) and along.refs[station].max() >= 107
        assert np.all(np.abs(along.refs[52:70] - places[52:70]) <= 2), along.refs[52:70]
        assert np.all(blind.refs[station] <= 103), blind.refs[station]


def test_road_matcher_follows_a_creep_with_the_anchored_cue() -> None:
    """A vehicle creeping at a quarter place a frame whose frames each differ from the one before by a small
    fraction of the moving steps before it: its first frames stand (the cue is relative to the moving steps),
    but against the last frame that moved the steps add up, motion shows every few frames, and the creep is
    followed."""
    matcher = get_matcher("stream-rules")
    places = np.concatenate([places_at_speeds([(1.0, 40)], start=50), places_at_speeds([(0.25, 120)], start=90)])
    theta = np.r_[np.arange(40) * 2.0, 80 + 0.1 * np.arange(120)]       # moving: unrelated views; creeping: 0.1 rad a frame
    enc = np.c_[np.cos(theta), np.sin(theta), np.zeros((160, 3))]
    enc[:40, 2:] = np.random.default_rng(0).normal(size=(40, 3))
    cue = matcher.cue(enc)
    assert (cue[41:44] >= matcher.still_threshold).all()                 # the creep's first frames stand ...
    assert (cue[100:] < matcher.still_threshold).any()                  # ... but the steps add up: motion shows
    for seed in range(4):
        sim = planted(np.random.default_rng(seed), 400, places)
        follows = matcher.run(sim, still=cue)
        late = slice(100, None)
        assert np.mean(np.abs(follows.refs[late] - places[late]) <= 2) > 0.9


def test_road_matcher_long_stop_held_with_the_motion_cue() -> None:
    """A stop of 120 frames on a mapped place, its view repeated with fresh noise: with the motion cue (the
    camera is seen to stand: its frames leave the state as it was) every stopped frame stays locked within 2
    places of the stop over eight noise draws; without it (the stop_gain rule alone) the lock fades in most
    draws."""
    matcher = get_matcher("stream-rules")
    held, held_blind = 0, 0
    for seed in range(8):
        rng = np.random.default_rng(seed)
        places = np.concatenate([places_at_speeds([(1.0, 80)], start=20), np.full(120, 100), places_at_speeds([(1.0, 60)], start=101)])
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
    matcher = get_matcher("stream-rules")
    for seed in range(8):
        rng = np.random.default_rng(seed)
        places = np.concatenate([places_at_speeds([(1.0, 60)], start=40), np.full(25, 100), places_at_speeds([(1.0, 40)], start=101)])
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
    matcher = get_matcher("stream-rules")
    places = np.concatenate([places_at_speeds([(1.0, 40)], start=50), np.full(10, -1), np.full(30, 300)])
    cues = np.full(len(places), 0.0)
    cues[51:] = 1.0
    stop = slice(50, 80)
    lost, parked = [], []
    for seed in range(8):
        res = matcher.run(planted(np.random.default_rng(seed), 600, places), still=cues)
        lost.append(np.mean(res.scores[stop] < matcher.min_confidence))
        parked.append(np.mean((res.refs[stop] == 300) & (res.scores[stop] >= matcher.min_confidence)))
    assert np.mean(lost) >= 0.9 and np.mean(parked) <= 0.1, (np.mean(lost), np.mean(parked))


def test_a_front_end_that_sees_every_image_alike_is_followed() -> None:
    """A front end whose encodings all lie within a cosine of 0.999 of each other (a network with random
    weights: one common direction, a little place-specific detail): the map is not read as standing, the
    camera's stops are, and the stream matcher follows the route from the encodings alone, as ``Localizer``
    runs it (``on_route`` on the references, the motion cue from the query encodings). With the cue's first
    step fixed in cosine units every frame read as standing and the matcher never moved."""
    rng = np.random.default_rng(21)
    n_refs, dim, eps = 120, 64, 0.02
    common = unit_rows(rng.normal(size=dim))
    detail = unit_rows(rng.normal(size=(n_refs, dim)))
    refs = unit_rows(common + eps * detail)
    places = places_at_speeds([(1.0, 30), (0.0, 8), (1.5, 30), (0.0, 6), (1.0, 20)], start=5.0)
    frames = unit_rows(common + eps * (detail[places] + 0.4 * unit_rows(rng.normal(size=(len(places), dim)))))
    assert (refs @ refs.T).min() > 0.998 and (frames @ refs.T).min() > 0.998
    matcher = get_matcher("stream-rules").on_route([refs])
    assert not matcher.route.any()
    cue = matcher.cue(frames)
    stop = np.r_[False, places[1:] == places[:-1]]
    settled = np.arange(len(places)) >= 1 + MIN_STEPS
    assert (cue[stop & settled] >= 0.5).mean() > 0.9 and (cue[~stop & settled] < 0.5).mean() > 0.9
    res = matcher.run(frames @ refs.T, k=1, still=cue)
    right = np.abs(res.refs - places) <= 2
    assert right[15:].mean() > 0.9 and (res.scores[15:] >= 1.0).mean() > 0.5


def test_road_matcher_stuck_rule_against_plain_loops() -> None:
    """A vehicle moving along places 1-12, then imagery of somewhere else that resembles place 14 while
    the cue says the camera moves (with two standing frames among it): the matcher's answers and scores, the
    stuck rule included, equal the plain loops', and the rule loses frames that it would answer without it."""
    rng = np.random.default_rng(11)
    places = np.concatenate([places_at_speeds([(1.0, 12)], start=1), -np.ones(14, int)])
    sim = planted(rng, 20, places, noise=0.3)
    sim[12:, 14] += 1.5
    cues = np.zeros(len(places))
    cues[[17, 18]] = 0.9   # a standing camera: these frames do not count
    params = {"vmax": 1.5, "grid": 2, "decay": 0.8, "bias": 0.5, "turn": 0.7, "memory": 50.0, "lock": 3.0,
              "rival_window": 2, "stop_gain": 0.3, "stop_decay": 0.95, "still": 0.5}
    for stuck in (0, 3):
        got = MATCHERS["stream-rules"].with_params(**params | {"stuck": stuck, "hub": -99.0}).run(sim, k=1, still=cues)
        want = naive_road(sim, **params, cues=cues, stuck=stuck)
        assert list(got.refs) == [r for r, _ in want]
        np.testing.assert_allclose(got.scores, [c for _, c in want], atol=1e-5)
        if stuck == 0:
            off = got.scores
    assert np.sum((got.scores < 1.0) & (off >= 1.0)) >= 3 and not np.any((got.scores >= 1.0) & (off < 1.0))


def test_road_matcher_trust_against_plain_loops() -> None:
    """A vehicle whose view of its place fades on about a third of its frames (its similarity there drops to
    the noise): the matcher's answers and scores equal the plain loops' with ``trust`` on and off, and with it
    on some of those weak views are answered (an unambiguous trajectory outweighs them)."""
    rng = np.random.default_rng(2)
    places = places_at_speeds([(1.0, 30)], start=1)
    sim = planted(rng, 40, places, noise=0.3)
    weak = np.flatnonzero(rng.random(len(places)) < 0.3)
    sim[weak, places[weak]] -= 1.0
    params = {"vmax": 1.5, "grid": 2, "decay": 0.8, "bias": 0.5, "turn": 0.7, "memory": 6.0, "lock": 3.0,
              "rival_window": 2, "stop_gain": 0.3, "stop_decay": 0.95, "still": 0.0, "evidence_decay": 0.0}
    scores = {}
    for trust in (1.0, 0.3):
        got = MATCHERS["stream-rules"].with_params(**params | {"trust": trust, "hub": -99.0}).run(sim, k=1)
        want = naive_road(sim, **params, trust=trust)   # the loops have no hub line
        assert list(got.refs) == [r for r, _ in want]
        np.testing.assert_allclose(got.scores, [c for _, c in want], atol=1e-5)
        scores[trust] = got.scores
    gained = (scores[0.3] >= 1.0) & (scores[1.0] < 1.0)
    assert gained.sum() >= 3 and not np.any((scores[1.0] >= 1.0) & (scores[0.3] < 1.0))
