"""The stream matcher in parts: each verdict judged alone over hand-made frames (``reading.FrameReading``),
and the trajectory recursion (``road.RoadMatcher``) handing each frame to whatever verdict it is given."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from vpr_edge.matchers import MATCHERS
from vpr_edge.matchers.lock import LockVerdict
from vpr_edge.matchers.probability import ProbabilityVerdict
from vpr_edge.matchers.reading import FrameReading, Judgement, TrajectoryOnly, answer_view
from vpr_edge.matchers.road import RoadMatcher
from vpr_edge.matchers.route import RouteGraph

from helpers import places_at_speeds, planted

RULES = {"lock": 6.0, "evidence": 1.5, "evidence_decay": 0.0, "hub": -99.0, "unique": 0.25, "confirm": 1, "stuck": 0, "trust": 1.0, "hold": 2.0}


def reading(values: np.ndarray, part: np.ndarray, standing: bool = False) -> FrameReading:
    ref = int(np.argmax(values))
    return FrameReading(ref, float(values[ref]), values, None, part, part, float(part.mean()), float(part.std()),
                        standing)


def naive_lock(values: np.ndarray, part: np.ndarray, rival_window: int) -> tuple[float, bool, str]:
    """The lock's rules on one frame of a one-drive map, as plain loops (evidence_decay 0: this frame alone)."""
    ref = int(np.argmax(values))
    best = values[ref]
    rival = max([v for i, v in enumerate(values) if abs(i - ref) > rival_window], default=0.0)
    here = max((part[i] - part.mean()) / part.std() for i in range(max(0, ref - 1), min(len(part), ref + 2)))
    uniqueness = 1 - (rival + 1) / (best + 1)
    why = "weak-view" if here < RULES["evidence"] else "no-trajectory" if best < RULES["lock"] else \
        "ambiguous" if uniqueness < RULES["unique"] else "locked"
    return float(why == "locked") + uniqueness, best >= RULES["hold"] * RULES["lock"], why


@pytest.mark.parametrize("case", ["locked", "weak-view", "no-trajectory", "ambiguous", "weak-but-locked"])
def test_the_lock_verdict_alone_against_its_rules(case: str) -> None:
    n = 60
    rng = np.random.default_rng(3)
    values = rng.uniform(0, 2, n)
    part = rng.normal(0, 1, n)
    values[30], part[30] = {"no-trajectory": 5.0, "weak-but-locked": 7.0}.get(case, 20.0), 4.0
    if case == "weak-view":
        part[29:32] = part.mean()
    if case == "ambiguous":
        values[50] = 19.0
    verdict = LockVerdict(RouteGraph.line(n), 10, **RULES)
    got = verdict.judge(reading(values, part))
    score, strong, why = naive_lock(values, part, 10)
    assert (got.why, got.strong) == (why, strong) and got.score == pytest.approx(score)
    assert why == case.replace("weak-but-", "")


def test_the_lock_verdicts_hub_line_against_a_loop() -> None:
    """The hub line alone: each frame's answer view less its place's mean over the stream's recent moving
    frames (an exponential memory per place, ``HUB_MEMORY``, shrunk by ``HUB_PRIOR`` against the place's
    sightings; plain loops), averaged as
    the evidence is, below ``hub`` -> "weak-view". A place that looks most like every frame is soon weak; the
    same views moving along the route stay locked; a stopped trajectory's frames neither teach the means nor
    lower the average."""
    from vpr_edge.matchers.constants import HUB_MEMORY, HUB_PRIOR

    n, rules = 40, RULES | {"evidence_decay": 0.5, "hub": 1.0}
    rng = np.random.default_rng(2)
    for case in ("hub", "moving", "stopped"):
        verdict = LockVerdict(RouteGraph.line(n), 5, **rules)
        mean, weight, seen, avg, whys, want = np.zeros(n), np.zeros(n), np.zeros(n), None, [], []
        for t in range(25):
            ref = 20 if case != "moving" else 5 + t
            values = np.zeros(n)
            values[ref] = 20.0
            part = rng.normal(0, 1, n)
            part[ref] += 6.0
            stopped = case == "stopped" and t >= 3
            whys.append(verdict.judge(FrameReading(ref, 20.0, values, None, part, part, float(part.mean()),
                                                   float(part.std()), False, stopped)).why)
            z = (part - part.mean()) / part.std()
            views = [z[i] - mean[i] * seen[i] / (seen[i] + HUB_PRIOR) for i in range(n)]
            if not stopped:
                for i in range(n):
                    seen[i] += 1
                    weight[i] = weight[i] * (1 - 1 / HUB_MEMORY) + 1
                    mean[i] += (z[i] - mean[i]) / weight[i]
            here = max(views[max(0, ref - 1):ref + 2])
            avg = here if avg is None else (max(avg, 0.5 * avg + 0.5 * here) if stopped else 0.5 * avg + 0.5 * here)
            want.append("weak-view" if avg < 1.0 else "locked")
        assert whys == want, case
        assert {"hub": "weak-view", "moving": "locked", "stopped": "locked"}[case] == whys[-1], (case, whys)


def test_the_lock_verdicts_evidence_is_averaged_over_frames_and_reset() -> None:
    n = 40
    rules = RULES | {"evidence_decay": 0.5}
    values = np.zeros(n)
    values[10] = 20.0
    strong_view = np.zeros(n)
    strong_view[10] = 10.0
    flat = np.r_[np.ones(n // 2), -np.ones(n // 2)]
    verdict = LockVerdict(RouteGraph.line(n), 5, **rules)
    assert verdict.judge(reading(values, strong_view)).why == "locked"
    here = verdict.judge(reading(values, flat))   # this frame alone is weak; the average is not
    assert here.why == "locked"
    verdict.reset()
    assert verdict.judge(reading(values, flat)).why == "weak-view"


def test_the_probability_verdict_alone() -> None:
    """No tail scale before the first frame with rivals: probability 0; then a lone peak far above its rivals
    is judged right, and the same frame with a rival as strong is not."""
    n = 200
    rng = np.random.default_rng(5)
    verdict = ProbabilityVerdict(RouteGraph.line(n), 10)
    part = rng.normal(0, 1, n)
    part[100] = 6.0
    values = rng.exponential(1.0, n)
    values[100] = 40.0
    first = verdict.judge(reading(values, part))
    assert isinstance(first, Judgement) and first.score < 1.0
    for _ in range(30):
        got = verdict.judge(reading(values, part))
    assert got.score > 0.9 and got.why in ("weak-view", "no-trajectory", "ambiguous")
    values[20] = 40.0
    rival = verdict.judge(reading(values, part))
    assert rival.score < 0.6 and rival.why == "ambiguous" and not rival.strong


def test_answer_view_stays_on_the_answers_drive() -> None:
    graph = RouteGraph(6, [0, 3])
    part = np.arange(6.0)
    assert answer_view(graph, 2, None, part).tolist() == [1.0, 2.0]   # the drive ends at place 2
    assert answer_view(graph, 3, None, part).tolist() == [3.0, 4.0]   # the next one starts at 3
    assert answer_view(graph, 4, None, part).tolist() == [3.0, 4.0, 5.0]
    assert answer_view(graph, 4, np.array([1, 3, 4, 5]), np.array([1.0, 3.0, 4.0, 5.0])).tolist() == [3.0, 4.0, 5.0]


class Recorder:
    """A verdict that records what the recursion hands it and says "strong" as told."""

    def __init__(self, graph: RouteGraph, rival_window: int, strong: bool) -> None:
        self.frames: list[FrameReading] = []
        self.strong = strong

    def judge(self, frame: FrameReading) -> Judgement:
        self.frames.append(frame)
        return Judgement(float(len(self.frames)), self.strong, "locked")

    def reset(self) -> None:
        self.frames.clear()


@pytest.mark.parametrize("strong", [True, False])
def test_the_recursion_hands_each_frame_to_its_verdict(strong: bool) -> None:
    """Every frame reaches the verdict with the places it searched, the answer at the best of their trajectory
    scores; the score and the reason are the verdict's; only a strong verdict lets a local search follow."""
    n = 1000
    rng = np.random.default_rng(2)
    sim = planted(rng, n, places_at_speeds([(1.0, 60)], start=100.0), noise=0.2)
    params = MATCHERS["stream"].params | {"window": 50}
    m = RoadMatcher(n, **params, verdict=lambda g, w: Recorder(g, w, strong))
    local = 0
    for i, row in enumerate(sim):
        wanted = m.wanted()
        local += wanted is not None
        ref, score = m.update(row if wanted is None else row[wanted], wanted)
        frame = m.verdict.frames[-1]
        assert score == i + 1 and m.why() == "locked" and frame.ref == ref and frame.best == pytest.approx(m.best())
        searched = np.arange(n) if wanted is None else wanted[:len(frame.values)]
        assert (frame.where is None) == (wanted is None) and np.array_equal(searched, frame.where if
                                                                           frame.where is not None else searched)
        assert frame.values.max() == pytest.approx(frame.best) and searched[np.argmax(frame.values)] == ref
    assert (local > 30) == strong and (local == 0) == (not strong)
    m.reset()
    assert m.verdict.frames == []


def test_the_decoy_reads_trajectories_only() -> None:
    m = RoadMatcher(50, **MATCHERS["stream-prob"].params | {"decoy": True, "lock": 6.0, "evidence": 1.5,
                                                           "evidence_decay": 0.5, "hub": 1.0, "unique": 0.25,
                                                           "confirm": 1, "stuck": 0, "trust": 1.0, "hold": 2.0})
    assert isinstance(m._decoy.verdict, TrajectoryOnly) and m._decoy._decoy is None and m._decoy.window == 0


def test_place_jumped_against_a_loop() -> None:
    """Whether the answer jumped (``lock.place_jumped``) against a plain test on a map of two drives: the first
    frame does; then a place of the frame before's drive more than the window from it does, a place of the
    other drive (the same road driven again, perhaps) does not."""
    from vpr_edge.matchers.lock import place_jumped

    rng = np.random.default_rng(5)
    graph, w = RouteGraph(40, np.array([0, 20])), 3
    refs = np.cumsum(rng.integers(-2, 3, 400)) % 40
    refs[::17] = rng.integers(0, 40, len(refs[::17]))   # and now and then anywhere
    prev = None
    for ref in map(int, refs):
        want = prev is None or ((prev < 20) == (ref < 20) and abs(ref - prev) > w)
        assert place_jumped(graph, prev, ref, w) == want
        prev = ref


@pytest.mark.parametrize("confirm", [1, 3])
def test_a_jump_is_answered_from_its_confirm_th_frame(confirm: int) -> None:
    """The lock verdict alone: a stream locked moving along places 5-14 whose best place jumps to 40 (a
    look-alike ahead; everything else as locked as before) is lost ("no-trajectory") on the jump's first
    ``confirm`` - 1 frames, and locked from there on, as the stream's first frames are; at confirm 1 (off)
    every frame is locked."""
    n = 60
    verdict = LockVerdict(RouteGraph.line(n), 10, **RULES | {"confirm": confirm})
    rng = np.random.default_rng(4)
    whys = []
    for t in range(16):
        ref = 5 + t if t < 10 else 40 + (t - 10)
        values, part = np.zeros(n), rng.normal(0, 1, n)
        values[ref], part[ref] = 20.0, 6.0
        whys.append(verdict.judge(reading(values, part)).why)
    assert whys[:10] == ["no-trajectory"] * (confirm - 1) + ["locked"] * (11 - confirm)
    assert whys[10:] == ["no-trajectory"] * (confirm - 1) + ["locked"] * (7 - confirm)


def test_place_advanced_against_a_loop() -> None:
    """Whether the answer moved on from where it last moved to (``lock.place_advanced``) against a plain test
    on a map of two drives: the first frame does; then a place of the anchor's drive at least one ahead of it
    or more than one behind it does, one behind or the same does not; another drive's place does."""
    from vpr_edge.matchers.lock import place_advanced

    rng = np.random.default_rng(6)
    graph = RouteGraph(40, np.array([0, 20]))
    refs = np.cumsum(rng.integers(-2, 3, 400)) % 40
    anchor = None
    for ref in map(int, refs):
        want = anchor is None or (anchor < 20) != (ref < 20) or ref - anchor >= 1 or ref - anchor < -1
        assert place_advanced(graph, anchor, ref) == want
        if want:
            anchor = ref


@pytest.mark.parametrize("cued", [True, False])
def test_an_answer_kept_while_the_camera_moves_is_lost_at_stuck(cued: bool) -> None:
    """The lock verdict alone: a stream locked moving along places 5-12, then kept at place 12 and 11 by turns
    (a place every frame resembles) while the motion cue says the camera moves: lost ("no-trajectory") from
    the ``stuck``-th such frame; frames of a standing camera do not count, and the answer moving on again is
    locked at once. Without a cue nothing says the camera moves: every frame stays locked."""
    n, stuck = 60, 4
    verdict = LockVerdict(RouteGraph.line(n), 10, **RULES | {"stuck": stuck})
    rng = np.random.default_rng(4)
    refs = list(range(5, 13)) + [12, 11, 12, 11, 11, 12, 11, 12] + [13, 14]
    standing = [False] * 8 + [False, False, True, True, False, False, False, False] + [False, False]
    whys = []
    for ref, stands in zip(refs, standing):
        values, part = np.zeros(n), rng.normal(0, 1, n)
        values[ref], part[ref] = 20.0, 6.0
        f = reading(values, part, stands)
        whys.append(verdict.judge(replace(f, cued=cued)).why)
    if not cued:
        assert whys == ["locked"] * len(refs)
        return
    # moving frames kept at 12 (anchor 12 from the 8th frame): 12, 11, (standing x2), 11, 12, 11, 12 -> 6
    kept = [0] * 8 + [1, 2, 2, 2, 3, 4, 5, 6] + [0, 0]
    assert whys == ["no-trajectory" if k >= stuck else "locked" for k in kept], whys


def test_a_weak_view_does_not_overrule_an_unambiguous_trajectory() -> None:
    """The lock verdict alone (``lock.lock_verdict``): a frame whose evidence average is below the line is lost
    ("weak-view") unless its uniqueness reaches ``trust``; the hub line is not overruled; at trust 1 (off)
    the evidence line alone decides, as a plain test of each case says."""
    from vpr_edge.matchers.lock import lock_verdict

    rng = np.random.default_rng(9)
    for _ in range(500):
        ev, uniq, hub = rng.uniform(0, 3), rng.uniform(0, 1), rng.uniform(-1, 3)
        trust = float(rng.choice([0.3, 0.6, 1.0]))
        got = lock_verdict(ev, 10.0, uniq, 1.5, 6.0, 0.25, hub, 1.0, 3, 3, 0, 4, trust)
        view = (ev >= 1.5 or uniq >= trust) and hub >= 1.0
        want = "weak-view" if not view else "ambiguous" if uniq < 0.25 else "locked"
        assert got == want, (ev, uniq, hub, trust)
