"""The streaming matcher for a vehicle on the road: any speed, stops, lock-on from anywhere, a lost state.

State: for every position on the route (a grid of 1/``grid`` reference steps) and every speed in
0, 1/grid, ..., ``vmax`` references per frame, the score H of the best recent trajectory ending there
(a decayed local-alignment sum in the manner of Smith-Waterman):

    H_t(v, p) = max(0, decay * max_v' [H_{t-1}(v', p - v) - turn * |v - v'| * grid] + z_t(p) - bias)

z_t is the frame's similarity row normalised twice: z-scored over the references (so that a frame whose
similarities are all low, as across seasons, counts as much as one whose are all high), then each
reference's running mean z over the last ~``memory`` frames is subtracted (frames while the best
trajectory is stopped are left out of that mean, so a long stop does not wash out its own place). The
second step removes hubs: references that resemble every query (a plain wall, a tunnel) would otherwise
collect evidence while the vehicle moves on, and a stopped trajectory parked on one beats the moving true
one (docs/design.md, "Matching"). ``bias`` is what a frame must beat to extend a
trajectory; ``turn`` charges each change of speed; ``decay`` forgets evidence older than about
1 / (1 - decay) frames. The max(0, .) lets a trajectory start anywhere (lock-on from anywhere, re-lock after
a detour) and floors hopeless ones.
Speed 0 is a state, so a stopped vehicle is followed; speed changes are cheap but not free, so
trajectories stay straight where the evidence allows (what makes SeqSLAM work) and bend where the vehicle
speeds up or slows down.

Standing still is not new evidence: a stopped camera sees one place again and again, and counting each
repeat in full let a trajectory parked on a look-alike (a hub, a station outside the map) outgrow the true
moving one and lock on where nothing is mapped. So at speed 0 a frame's excess z - bias counts only
``stop_gain`` of itself when positive (in full when negative), and the state decays by ``stop_decay``
instead of ``decay``, holding a lock through a stop rather than rebuilding it. (What it
changed on the derived streams: docs/results.md, "Evaluating".)

Whether the vehicle stands is also seen in the query stream itself, without the map: a standing camera sees
the same view again, so its frames' encodings are alike the last frame that moved, far more alike than the
stream's moving frames are to each other. ``update``'s ``still`` is that motion cue (``motion.MotionCue``: 1 =
the same view, 0 = as far as this stream's typical moving step); a frame with a cue of at least ``still``
shows the camera standing: its view again, which says nothing new about where the vehicle is, so the frame
leaves the state as it was (no decay, no gain, no move along the route, hub means not updated) and the answer
stays. A lock thus holds through a stop of any length, a stop where nothing was locked (off the map, in front
of a look-alike) builds no lock, a trajectory cannot run on past the stop place on the next places' likeness
to the repeated view, and a crawl shown as repeated frames is followed at its speed in the frames that move.
A frame less alike is motion: speed 0 gains nothing and decays as the other speeds do, so a stopped or parked
hypothesis cannot keep the lead while the camera moves on. Without a cue (the first frame, a bare similarity
matrix, ``still`` = 0) the ``stop_gain`` / ``stop_decay`` rule above holds for every frame.

The map's own drive may have stood too (``route``: the references that stand by the same cue along the map,
``motion.route_stands``; a train at a station): its references there show one view, and a standing frame
answered just before such a reference is read as motion, so the answer moves on through the map's standing
references as the frames of the mapping drive did (where it stands still, the answer would stay at the first
of them while the rest of that stop, the same place, went by).

The answer is the position of the best state. How sure it is, and why a frame is lost, is the *verdict*'s:
the lock's rules (``lock.LockVerdict``; each frame handed over as a ``lock.FrameReading``), described here.
Its score does two jobs, so it has two parts:

    score = [H_best >= lock and held >= confirm and not kept >= stuck
             and (E >= evidence or uniqueness >= trust) and uniqueness >= unique] + uniqueness,
    uniqueness = 1 - (H_rival + 1) / (H_best + 1)

H_best is about the summed excess of z over ``bias`` along the last ~1/(1 - decay) frames: below ``lock``
no trajectory fits well enough and the frame is lost (the registry's min_confidence is 1.0: "locked").
E is how far the answer stands out of what the frame sees: the answer's similarity (the best within one
reference) in standard deviations above the frame's similarities to the route (the frame's mean and spread,
as z uses them; the bulk of a row is the "not this place" distribution of that frame, whatever the route or
conditions), averaged over frames (E = evidence_decay * E + (1 - evidence_decay) * e; a standing frame may
raise E, never lower it). H remembers ~1/(1 - decay) frames, so alone it reports a vehicle that left the
map lost only after that memory fades; E says so within a frame or two. A weak view does not overrule an
unambiguous trajectory, though: a frame whose uniqueness (below) reaches ``trust`` is answered whatever its E
(a front end whose single frames are weak gives many weak views of places its trajectories hold well).
H_rival is the best trajectory ending more than ``rival_window`` references away (or more than the map's
``reach``, how far along it references stay alike, ``likeness.reach``, where that is further: on a densely
sampled map a trajectory a few places on shares the answer's evidence and is no rival): like SeqSLAM's
best/second-best ratio, uniqueness ranks frames by how unambiguous the answer is, which H alone does badly,
while H decides lost better than uniqueness (docs/design.md, "Matching"). An answer whose uniqueness is below
``unique`` (a trajectory elsewhere along the answer's drive nearly as strong: either could be the place) is
lost too, so that the vehicle is told nothing rather than a coin's toss; a rival on another drive of a map of
several does not count there, as that drive may be the same road driven again. ``held`` counts the frames
the best trajectory's place has held (each within ``rival_window`` of the frame before's, along its drive):
a trajectory that ran ahead on a lock's remembered score onto a look-alike off the map waits ``confirm``
frames, by when that score has decayed (``lock.place_jumped``). ``kept`` counts the frames the camera moved
(the motion cue says so; without one the rule is off: a stop's best trajectory creeps on by half-references)
while the answer's place did not move on by a reference: at ``stuck`` the frame is lost, as a place that every
frame of a moving camera resembles (imagery of somewhere else) is no trajectory of the map
(``lock.place_advanced``). So locked frames rank above lost ones, each by uniqueness, and ``--min-confidence``
between 1 and 2 asks for a more unambiguous answer still.

The state and its recursion are ``trajectories.TrajectoryState``'s; the parameters, ``stream_config.StreamConfig``
(from ``params.STREAM_RULES``). The max over speeds with the speed penalty is a distance transform (two passes over the
speeds), so a frame costs O(grid * speeds * R) vectorised work in preallocated buffers, and the state is
(grid * speeds + 1) * R floats, whatever the stream's length.

Local search (``window`` > 0, used on routes of more than 4 * window references): while the best trajectory is
firmly locked (H >= ``hold`` * lock, and no trajectory more than ``window`` references away has half its H),
the next frame updates only the references within ``window`` of the answer, and ``wanted()`` asks for just
their similarities plus those of ``probe`` fixed random references, from which the frame's mean and spread
(the z-score's) are estimated. State outside the window is held at 0. ``span`` frames in every ``check``
firmly locked frames, and every frame that is not firmly locked, search the whole route, so a stronger
hypothesis elsewhere (a jump, a re-entry after a detour) is found. A frame then costs O(window) instead of
O(R), plus the global frames. Each reference's running mean counts time, not updates: seen again after k
frames outside the window, its old mean is weighted by (1 - 1/memory)^k.
"""
from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from vpr_edge.matchers.base import NO_TRAJECTORY
from vpr_edge.matchers.constants import FIRM_RIVAL, LOCAL_ROUTE, MIN_SPREAD
from vpr_edge.matchers.lock import FrameReading, LockVerdict
from vpr_edge.matchers.motion import stands
from vpr_edge.matchers.search_policy import around_candidates, best_hypotheses, local_next
from vpr_edge.matchers.route import Intervals, RouteGraph, max_outside, places
from vpr_edge.matchers.stream_config import StreamConfig
from vpr_edge.matchers.trajectories import TrajectoryState, per_reference


class RoadMatcher(TrajectoryState):
    """Online matcher over (position, speed) trajectories; see the module docstring."""

    searches_locally = True

    def __init__(self, n_refs: int, config: StreamConfig, route: np.ndarray | None = None,
                 graph: RouteGraph | None = None, reach: int = 0) -> None:
        """``config``: the parameters (``stream_config.StreamConfig``, from ``matchers.params.STREAM_RULES``).
        ``route``: (n_refs,) bool, the references where the map's drive stood (``motion.route_stands``; None:
        not known). ``graph``: the map's drives and where they meet (``route.RouteGraph``; None: one drive).
        ``reach``: how far along the map references stay alike (``likeness.reach``; 0: not known): a rival
        trajectory must lie beyond it as well as beyond ``rival_window``. Each frame is judged by the lock's
        rules (``lock.LockVerdict``, with ``config.rules``)."""
        if n_refs < 1:
            raise ValueError("need at least one reference")
        model, search = config.model, config.search
        self.config = config
        self._why = NO_TRAJECTORY   # why the last frame is not answered, as its verdict said (``why``)
        if route is not None and np.shape(route) != (n_refs,):
            raise ValueError(f"route must flag each of the {n_refs} references, got shape {np.shape(route)}")
        self.route = None if route is None else np.asarray(route, bool)
        # local search pays only where the window is a small part of the route
        self.window = int(search.window) if search.window and n_refs > LOCAL_ROUTE * search.window else 0
        # references whose similarities estimate a frame's mean and spread while searching locally: a fixed
        # random sample, so that the estimate costs O(probe), not O(R)
        self._probe = np.sort(np.random.default_rng(0).choice(n_refs, min(n_refs, search.probe), replace=False))
        graph = RouteGraph.line(n_refs) if graph is None else graph
        if graph.n_refs != n_refs:
            raise ValueError(f"route graph of {graph.n_refs} references for {n_refs}")
        n_speeds = int(round(model.vmax * model.grid)) + 1
        super().__init__(n_refs, model.grid, n_speeds, model.decay, model.turn, graph)
        rival_window = max(0, int(config.rules.rival_window), int(reach))
        self.verdict = LockVerdict(graph, replace(config.rules, rival_window=rival_window))
        self._gap = -(-n_speeds // model.grid) + 1   # windows closer than this are searched as one
        self._win: Intervals | None = None   # references the next frame searches ([lo, hi) intervals); None = all
        self.seek, self.peaks = max(0, int(search.seek)), max(1, int(search.peaks))
        self._last: tuple[np.ndarray, np.ndarray | None] = (np.zeros(0, np.float32), None)   # (``best_hypotheses``)
        self.check, self.span = max(1, int(search.check)), max(0, int(search.span))
        self._held = 0                               # frames since the local search began
        self._mean = np.zeros(n_refs)     # running mean z per reference
        self._stopped = False
        self._position: float | None = None   # the last answer on the reference grid (``position``)
        self._best = 0.0                       # the last frame's best trajectory score (``best``)
        # per reference, the decayed number of frames in its mean (starts as if `memory` frames of mean 0) and
        # the frame count when it was last seen (-1: never): a reference outside a local search's window is not
        # updated, and when seen again its old mean weighs as much as its age allows (an EMA over time, not over
        # updates); the prior does not age: a reference first seen late (a large map searched around an
        # index's candidates) starts from it as one seen at the first frame does, so that its first sighting
        # does not become its whole mean and cancel the next frame's evidence there
        self._weight = np.full(n_refs, float(model.memory))
        self._seen = np.full(n_refs, -1, np.int64)
        self._t = 0                       # frames counted for the means (not those of a stopped vehicle)

    def best(self) -> float:
        """The last frame's best trajectory score H (0 before a frame)."""
        return self._best

    def position(self) -> float | None:
        """The best state's position on the 1/``grid`` reference grid, in references (None before a frame)."""
        return self._position

    def wanted(self) -> np.ndarray | None:
        """References (int array) whose similarities the next ``update`` needs, in that order; None:
        all of them. While locked on a large route (``window`` > 0): the ``window`` references either side of
        the answer, then the probe sample."""
        if self._win is None:
            return None
        return np.concatenate([places(self._win), self._probe])

    def _normalise(self, s: np.ndarray, lo: int, mean: float, std: float) -> np.ndarray:
        """Similarities of references [lo, lo + len(s)) -> z-scored with the frame's ``mean`` and ``std`` over
        all references, minus each reference's running mean."""
        z = (s - mean) / max(std, MIN_SPREAD)
        run, weight = self._mean[lo:lo + len(s)], self._weight[lo:lo + len(s)]
        out = z - run
        if not self._stopped:   # frames of a stopped vehicle repeat one place: they say nothing of hubs
            seen = self._seen[lo:lo + len(s)]
            keep = 1.0 - 1.0 / self.config.model.memory
            if len(seen) == self.n_refs and seen.min() == seen.max() == self._t - 1:   # a whole-route pass
                weight *= keep                                   # after another: every age one frame
            else:
                weight *= keep ** np.where(seen < 0, 1, self._t - seen)
            weight += 1.0
            seen[:] = self._t
            run += (z - run) / weight
        return out

    def stands(self, still: float | None) -> bool:
        """Whether a frame with motion cue ``still`` shows a standing camera (its view again) where the map's
        drive moved on: such a frame leaves the state as it was (see the module docstring)."""
        if not stands(still, self.config.model.still):
            return False
        if self.route is None or self._position is None:
            return True
        nxt = int(round(self._position)) + 1
        return not (nxt < self.n_refs and self.route[nxt])

    def _cued(self, still: float | None) -> bool:
        """Whether a frame with motion cue ``still`` is read by the cue (one is given and ``still`` is not 0)."""
        return still is not None and bool(self.config.model.still)

    def _stop_rule(self, still: float | None) -> tuple[float, float]:
        """(share of a positive z counted at speed 0, speed 0's decay) for a frame that moves, with motion cue
        ``still`` (see the module docstring)."""
        if not self._cued(still):
            return self.config.model.stop_gain, self.config.model.stop_decay
        return 0.0, self.decay

    def update(self, sim_row: np.ndarray, refs: np.ndarray | None = None,
               still: float | None = None) -> tuple[int, float]:
        """Similarities of the new frame -> (reference at the best state, score in [0, 2); >= 1: locked).
        ``sim_row`` covers every reference (R,), or with ``refs`` exactly the references ``wanted()`` named;
        ``still``: the frame's motion cue (cosine similarity to the last moving frame's encoding,
        ``base.MotionCue``; None: none)."""
        s = np.asarray(sim_row, np.float64)
        wins = self._win if self._win is not None else [(0, self.n_refs)]
        where = None if self._win is None else places(wins)   # the places searched (None: all, in order)
        n_win = self.n_refs if where is None else len(where)
        if refs is not None:
            if self._win is None or len(refs) != n_win + len(self._probe) or len(s) != len(refs):
                raise ValueError("similarities must cover the references wanted() named")
            part, probe = s[:n_win], s[n_win:]
        elif s.shape != (self.n_refs,):
            raise ValueError(f"similarity row must have shape ({self.n_refs},), got {s.shape}")
        else:
            part = s if where is None else s[where]
            probe = s[self._probe] if self._win is not None else s
        g = self.grid
        mean, std = float(probe.mean()), max(float(probe.std()), MIN_SPREAD)
        standing = self.stands(still)
        if not standing:   # a standing camera's view again says nothing new: the state stays
            fed = self._fed()
            at = 0
            self._t += not self._stopped   # frames counted for the means (``_normalise``), once a frame
            if self._win is None:   # the whole route: its buffers
                self._densify()
                z = self._zbuf.reshape(n_win, g)
            else:
                z = np.empty((n_win, g), np.float32)
            for lo, hi in wins:
                z[at:at + hi - lo] = self._normalise(part[at:at + hi - lo], lo, mean, std)[:, None]
                at += hi - lo
            z = z.reshape(-1)
            z -= self.config.model.bias
            gain, decay = self._stop_rule(still)
            if self._win is None:
                self._advance(0, self.n_refs * g, z, gain, decay, fed)
            else:
                self._advance_many(wins, z, gain, decay, fed)
        elif self._win is None:
            self._densify()
        ref, best, col, stopped, per_ref = -1, -1.0, 0, False, []
        off = 0
        for lo, hi in wins:   # the state is held over exactly these windows, in order
            if self._kept is None:
                h = self._full[:, lo * g:hi * g]
            else:
                h = self._vals[:, off:off + (hi - lo) * g]
                off += (hi - lo) * g
            flat = int(np.argmax(h))
            if float(h.flat[flat]) > best:
                best, ref = float(h.flat[flat]), lo + (flat % h.shape[1]) // g
                col, stopped = lo * g + flat % h.shape[1], flat < h.shape[1]
            per_ref.append(per_reference(h, g))
        self._stopped = stopped                    # the best trajectory has speed 0
        self._position = col / g
        self._best = best                          # the best trajectory's score (``best``)
        values = per_ref[0] if len(per_ref) == 1 else np.concatenate(per_ref)
        self._last = (values, where)   # for ``around``'s hypotheses held
        # without a motion cue, a best trajectory at speed 0 is what says the vehicle stands; with one, the cue
        judged = self.verdict.judge(FrameReading(ref, best, values, where, part, probe, mean, std, standing,
                                                 stopped and still is None, self._cued(still)))
        score, self._why = judged.score, judged.why
        # a firm lock: a strong answer, and no trajectory beyond the window half as strong (seen in global frames)
        held = bool(self.window) and judged.strong and \
            max_outside(values, where, self.graph.near(ref, self.window)) < FIRM_RIVAL * best
        self._follow(ref, held)
        return ref, score

    def why(self) -> str:
        """Why the last frame is not answered, as its verdict says (``base.LOST_WHY``; "locked" when it is);
        the lock's rules: "weak-view" (its answer does not stand out of what the frame sees: E < ``evidence``
        and uniqueness < ``trust``), "no-trajectory" (none has built up: H < ``lock``, its place has held fewer
        than ``confirm`` frames, or it has kept one place while the camera moved ``stuck`` frames), "ambiguous"
        (a rival along the drive nearly as strong: uniqueness < ``unique``)."""
        return self._why

    def probability(self) -> None:
        """The lock's rules model no probability that the answer is right: None."""
        return None

    def _follow(self, ref: int, held: bool) -> None:
        """Choose the next frame's search: the references within ``window`` of ``ref`` along the route
        (``RouteGraph.near``: across a junction too) while firmly locked (``window`` > 0), except for ``span``
        global frames every ``check`` frames, else everything. State outside the window is kept at 0
        (trajectories there are dropped when the window is entered and when it moves on)."""
        self._held = self._held + 1 if (self.window and held) else 0
        if not local_next(self._held, self.check, self.span):
            self._win = None
            return
        self._search(self.graph.near(ref, self.window, self._gap))

    def _search(self, win: Intervals) -> None:
        """Search ``win`` next frame; the state outside it is dropped (0), the rest held compact."""
        cols = self._state_cols(win)
        self._hold(win, cols, self._take(cols))
        self._win = win

    def around(self, candidates: np.ndarray) -> np.ndarray:
        """What the next ``update`` needs when ``wanted()`` asked for the whole route and an index answered
        with ``candidates`` (places, e.g. a frame's most similar references by ``index.ivf``): the places
        within ``seek`` of each candidate along the route and the neighbourhoods of the best hypotheses held
        (``peaks`` of them, ``window``/4 places either side), then the probe. Hypotheses elsewhere are
        dropped: the state lives around candidates, not over every place."""
        reach = max(self.seek, self.window // 4)
        hypotheses = best_hypotheses(*self._last, self.peaks, reach)
        self._search(around_candidates(self.graph, candidates, self.seek, hypotheses, reach, self._gap))
        return np.concatenate([places(self._win), self._probe])

    def reset(self) -> None:
        """Forget the stream."""
        self._position = None
        self._best = 0.0
        self.verdict.reset()
        self._why = NO_TRAJECTORY
        self._hold([], np.zeros(0, np.int64), np.zeros((self.n_speeds, 0), np.float32))
        self._mean[:] = 0.0
        self._stopped = False
        self._weight[:] = self.config.model.memory
        self._seen[:] = -1
        self._t = 0
        self._win = None
        self._last = (np.zeros(0, np.float32), None)
        self._held = 0


def stream_matcher(n_refs: int, *, route: np.ndarray | None = None, graph: RouteGraph | None = None,
                   reach: int = 0, **params: Any) -> RoadMatcher:
    """The registry's ``stream-rules`` (``params.STREAM_RULES``); ``route``, ``graph`` and ``reach`` are the map's
    (``Matcher.on_route``)."""
    return RoadMatcher(n_refs, StreamConfig.of(params), route, graph, reach)


stream_matcher.searches_locally = RoadMatcher.searches_locally   # type: ignore[attr-defined]
