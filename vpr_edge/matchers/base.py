"""The matcher contract: a similarity matrix or a stream of similarity rows in, one reference per frame out.

Conventions: ``sim`` is (Q, R), query frames by rows, reference places by columns, higher = more alike.
Every matcher answers, per query frame, its best reference, a score (higher = more confident; what ranks
frames for a precision-recall curve and what ``--min-confidence`` thresholds into a lost state) and a
ranked list of candidate references (best first, for recall@K).

An *online* matcher sees one row at a time, past frames only: ``update(row) -> (ref, score)``, then
``ranking()`` gives its per-reference preference for that frame. Running it over a matrix row by row is its
offline form, so every matcher, online or not, can be evaluated with ``run(sim)``.

An online matcher may also take a motion cue per frame, ``still`` (``motion``: 1 = the same view as the last
frame that moved, 0 = as far from it as a typical moving step of this stream; None: not known, as for the first
frame or a bare similarity matrix). A frame *stands* when its cue is at least the matcher's ``still``
parameter (``motion.stands``). A matcher that also reads the map's own stops (``reads_route``) gets them with
``Matcher.on_route`` (``motion.route_stands`` of the references). Matchers without a use for the cue ignore it.

An online matcher may search locally: ``wanted()`` names the references whose similarities its next frame
needs (None: all, what ``WholeRoute`` matchers always answer), and ``update(values, refs)`` takes just those.
``step`` drives every online matcher that way, so that the Localizer computes only the similarities asked for
and ``evaluate`` measures exactly what it runs.

A matcher's parameters are defined once, with their meaning, in ``params``; the registry's presets and the
CLI's help read them there.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

import numpy as np

from vpr_edge.errors import InputError, Message, VprError
from vpr_edge.matchers.likeness import LikenessSample
from vpr_edge.matchers.constants import MEMORY
from vpr_edge.matchers.motion import MotionCue, cue_at, route_stands, stillness
from vpr_edge.matchers.params import Param, read_items
from vpr_edge.matchers.route import RouteGraph


class OnlineMatcher(Protocol):
    """A matcher fed one frame at a time, with memory bounded independently of the stream's length.
    ``searches_locally``: some frames read only part of the route (``wanted()``), so whole-route frames may
    be approximated on large maps (``index.coarse``); False: every frame reads every reference exactly."""

    searches_locally: bool

    def wanted(self) -> np.ndarray | None:
        """References (sorted int array) whose similarities the next ``update`` needs; None: all of them."""

    def update(self, sim_row: np.ndarray, refs: np.ndarray | None = None,
               still: float | None = None) -> tuple[int, float]:
        """Similarities of the new frame to the references ``refs`` (what ``wanted()`` asked for; None: all
        R, ``sim_row`` (R,)) and its motion cue ``still`` (see the module docstring) -> (best reference,
        score)."""

    def ranking(self) -> np.ndarray:
        """Per-reference preference (R,) after the last update (higher = better); ties broken by index."""

    def position(self) -> float | None:
        """Where the last answer lies in references, finer than one (the stream's half-reference grid: 41.5
        is half-way from reference 41 to 42); None: at the answered reference."""

    def why(self) -> str | None:
        """Why the last frame is not confidently answered, one of ``LOST_WHY``, or "locked" when it is; None:
        the matcher gives no reason (``lost_why`` turns this into a lost frame's reason)."""

    def probability(self) -> float | None:
        """The probability that the last frame's answer is right; None: the matcher models none."""

    def reset(self) -> None:
        """Forget the stream."""


class StreamRows(Protocol):
    """A stream's rows as an online matcher reads them (``Matcher.run``'s ``search``): frame ``i``'s
    similarities to the references ``refs`` (None: all), and what ``step`` asks an index for it (None: no
    index); frames are asked in order."""

    def rows(self, i: int, refs: np.ndarray | None) -> np.ndarray: ...

    def candidates(self, i: int) -> Callable[[], np.ndarray] | None: ...


class WholeRoute:
    """Base of online matchers that read every reference every frame (``wanted()`` is always None)."""

    searches_locally = False

    def wanted(self) -> None:
        return None

    def position(self) -> None:
        return None

    def why(self) -> None:
        return None

    def probability(self) -> None:
        return None


@dataclass(frozen=True)
class Result:
    """Per query frame: ``refs`` (Q,) int best reference, ``scores`` (Q,) float confidence (higher = more
    confident), ``ranked`` (Q, k) int candidate references, best first (``ranked[:, 0] == refs``)."""

    refs: np.ndarray
    scores: np.ndarray
    ranked: np.ndarray
    why: np.ndarray | None = None   # (Q,) object: each frame's ``OnlineMatcher.why()`` (None: not given)
    probability: np.ndarray | None = None   # (Q,) the probability each answer is right (None: not modelled)


def top_k(pref: np.ndarray, k: int) -> np.ndarray:
    """The ``k`` highest entries of each row of ``pref`` (..., R), best first -> (..., min(k, R)) int.
    Ties go to the lower index."""
    k = min(k, pref.shape[-1])
    part = np.argpartition(-pref, k - 1, axis=-1)[..., :k]
    vals = np.take_along_axis(pref, part, -1)
    order = np.lexsort((part, -vals), axis=-1)
    return np.take_along_axis(part, order, -1)


def lead_with(refs: np.ndarray, cand: np.ndarray) -> np.ndarray:
    """Candidates (Q, k) reordered so that each row starts with its answer ``refs`` (Q,), the others after
    it in their order (the last one dropped if the answer was not among them)."""
    marked = np.where(cand == refs[:, None], -1, cand)
    order = np.argsort(marked == -1, axis=1, kind="stable")
    rest = np.take_along_axis(marked, order, 1)
    return np.concatenate([refs[:, None], rest[:, : cand.shape[1] - 1]], axis=1)


def step(matcher: OnlineMatcher, similarity: Callable[[np.ndarray | None], np.ndarray],
         still: float | None = None, candidates: Callable[[], np.ndarray] | None = None) -> tuple[int, float]:
    """One frame: ``similarity(refs)`` gives the frame's similarities to the references ``refs`` (sorted int
    array; None = all, (R,)); ``refs`` is what the matcher's ``wanted()`` asks for, if it has one. ``still``:
    the frame's motion cue (``stillness``), passed on. ``candidates()``: the frame's most similar references
    by an index (``index.ivf``; None: no index): where the matcher asks for the whole route and can search
    around candidates (``around``), it gets those instead of every reference."""
    refs = matcher.wanted()
    if refs is None and candidates is not None and callable(getattr(matcher, "around", None)):
        refs = matcher.around(candidates())
    return matcher.update(similarity(refs), refs, still)


def run_online(matcher: OnlineMatcher, sim: np.ndarray, k: int = 10, still: np.ndarray | None = None) -> Result:
    """Feed the rows of ``sim`` (Q, R) to an online matcher in order (through ``step``: a local search sees
    only the references it asks for), with each frame's motion cue from ``still`` (Q,) if given; collect its
    answers and top-k."""
    return run_rows(matcher, lambda i, idx: sim[i] if idx is None else sim[i, idx], sim.shape[0], sim.shape[1], k,
                    still)


def run_rows(matcher: OnlineMatcher, rows: Callable[[int, np.ndarray | None], np.ndarray], q: int, r: int,
             k: int = 10, still: np.ndarray | None = None,
             candidates: Callable[[int], Callable[[], np.ndarray] | None] | None = None) -> Result:
    """``run_online`` with frame i's similarities to references ``idx`` (None: all R) given by
    ``rows(i, idx)``, for rows computed on demand (a coarse whole-route search: ``map.search``, ``python -m
    vpr_edge_bench coarse-check``); ``candidates(i)``: what ``step`` asks an index for frame i (None: no
    index)."""
    if still is not None and len(still) != q:
        raise ValueError(f"need a motion cue per frame: {len(still)} for {q} frames")
    refs = np.empty(q, np.int64)
    scores = np.empty(q, np.float64)
    ranked = np.empty((q, min(k, r)), np.int64)
    why = np.empty(q, object)
    probability = np.full(q, np.nan)
    for i in range(q):
        refs[i], scores[i] = step(matcher, lambda idx: rows(i, idx), cue_at(still, i),
                                  None if candidates is None else candidates(i))
        ranked[i] = top_k(matcher.ranking(), k)
        why[i] = matcher.why()
        p = matcher.probability()
        probability[i] = np.nan if p is None else p
    return Result(refs, scores, lead_with(refs, ranked), None if all(w is None for w in why) else why,
                  None if np.isnan(probability).all() else probability)


@dataclass(frozen=True)
class Matcher:
    """A registered matcher: a name, a one-line summary, and either ``start(n_refs, **params)`` making an
    online matcher or ``align(sim, k, **params)`` computing a Result offline. ``definitions`` defines its
    parameters (``params.Param``: default and meaning); ``params`` are the values it runs with (default: the
    definitions' defaults; a preset changes some); ``with_params`` overrides some of them. ``min_confidence``:
    the default score below which a frame is reported lost (None: the matcher has no lost state). ``scores``:
    the (Q, R) matrix it runs on: ``cosine`` similarities of encodings, or ``svm`` decision values (a map built
    with --svm)."""

    name: str
    summary: str
    start: Callable[..., OnlineMatcher] | None = None
    align: Callable[..., Result] | None = None
    definitions: dict[str, Param] = field(default_factory=dict)
    params: dict[str, Any] = field(default_factory=dict)
    min_confidence: float | None = None
    scores: str = "cosine"
    probability: bool = False                 # its score is the probability that the answer is right
    reads_route: bool = False                 # start() takes ``route`` (the map's standing references),
    route: np.ndarray | None = field(default=None, repr=False, compare=False)   # ``graph`` (its drives) and
    graph: RouteGraph | None = field(default=None, repr=False, compare=False)   # ``reach`` (likeness.reach)
    reach: int = field(default=0, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not self.params:
            object.__setattr__(self, "params", {k: p.default for k, p in self.definitions.items()})
        if set(self.params) != set(self.definitions):
            raise ValueError(f"matcher {self.name!r}: parameters {sorted(self.params)} do not match their "
                             f"definitions {sorted(self.definitions)}")

    def lost_line(self, min_confidence: float | None = None, target_precision: float | None = None,
                  live: bool = False, line: Callable[[float], float] | None = None) -> float | None:
        """The score below which this matcher's answers are lost: ``min_confidence`` if given (checked:
        ``check_lost_line``), else with a ``target_precision`` (checked: ``check_target_precision``) and a
        ``line`` (a labelled drive's score at each precision: ``calibration.Curve.line``) the score it gives,
        else for a matcher whose score is a probability (``probability``) the ``target_precision``, else its own
        ``min_confidence`` (None: no lost state). ``live``: the line of a stream the matcher answers
        (``Localizer``), where a target precision is nothing but the line: given to a matcher whose score is no
        probability, without a ``line``, InputError (``evaluate`` also reads every mode's best line at it)."""
        given = check_lost_line(min_confidence)
        target = check_target_precision(target_precision)
        if live and target is not None and not self.probability and line is None:
            raise InputError("{opt.target_precision} {v}: mode {name}'s score is not the probability that its "
                             "answer is right, so no target precision sets its line ({opt.min_confidence} does, "
                             "or a {opt.calibration} from a labelled drive; stream's score is one)",
                             v=target, name=self.name)
        if given is not None:
            return float(given)
        if target is not None and line is not None:
            return float(line(target))
        return target if self.probability and target is not None else self.min_confidence

    def params_help(self) -> str:
        """One line per parameter: name, value and meaning (``localize --list-params``)."""
        return "\n".join(f"  {k} = {v!r}: {self.definitions[k].meaning}" for k, v in self.params.items())

    @property
    def online(self) -> bool:
        """True if it can run on a live stream (past frames only)."""
        return self.start is not None

    @property
    def searches_locally(self) -> bool:
        """Whether the online matchers it starts search locally (``OnlineMatcher.searches_locally``, as the
        class or factory ``start`` declares it); False for an offline one."""
        return bool(getattr(self.start, "searches_locally", False))

    def with_params(self, **overrides: Any) -> "Matcher":
        """The same matcher with some parameters changed; unknown names raise ValueError."""
        unknown = set(overrides) - set(self.params)
        if unknown:
            raise ValueError(f"matcher {self.name!r} has no parameter(s) {', '.join(sorted(unknown))}")
        return replace(self, params=self.params | overrides)

    def parse_params(self, items: Sequence[str]) -> dict[str, Any]:
        """``["key=value", ...]`` (the CLI's ``--param``) -> overrides of this matcher's parameters, each value
        read as its default's type (bool: true/false/1/0). ValueError naming the item for an unknown key, a
        value that does not read, or one the matcher refuses (checked by a run on a small random matrix)."""
        out = read_items(items, self.params, self.name)
        if out:
            try:
                self.with_params(**out).run(np.random.default_rng(0).random((3, 3)), 1)
            except ValueError as e:
                said = e.args[0] if len(e.args) == 1 and isinstance(e.args[0], Message) else str(e)
                raise ValueError(Message("{opt.params} {items}: {name}: {e}", items=" ".join(items), name=self.name,
                                         e=said)) from None
        return out

    def stream(self, n_refs: int) -> OnlineMatcher:
        """A fresh online matcher over ``n_refs`` references."""
        if self.start is None:
            raise ValueError(f"matcher {self.name!r} is offline only")
        if self.reads_route:
            if self.route is not None and len(self.route) != n_refs:
                raise ValueError(f"matcher {self.name!r}: route of {len(self.route)} references for {n_refs}")
            if self.graph is not None and self.graph.n_refs != n_refs:
                raise ValueError(f"matcher {self.name!r}: drives of {self.graph.n_refs} references for {n_refs}")
            return self.start(n_refs, route=self.route, graph=self.graph, reach=self.reach, **self.params)
        return self.start(n_refs, **self.params)

    @property
    def still_threshold(self) -> float | None:
        """The cue at or above which a frame stands for this matcher (its ``still`` parameter; None: it
        reads no motion cue)."""
        return self.params.get("still") or None

    @property
    def still_memory(self) -> int:
        """Moving frames whose median step is the motion cue's typical step (its ``still_memory``)."""
        return int(self.params.get("still_memory", MEMORY))

    def motion_cue(self) -> MotionCue:
        """A fresh ``motion.MotionCue`` with this matcher's threshold and memory (``still``,
        ``still_memory``): what ``Localizer`` runs frame by frame."""
        return MotionCue(self.still_threshold, self.still_memory)

    def cue(self, encodings: np.ndarray) -> np.ndarray:
        """Each frame's motion cue (Q,) for this matcher from the stream's encodings (Q, D), as
        ``motion_cue`` gives it frame by frame (NaN where there is none)."""
        return stillness(encodings, self.still_threshold, self.still_memory)

    def on_route(self, blocks: Iterable[np.ndarray], graph: RouteGraph | None = None) -> "Matcher":
        """This matcher on a map whose references are given in route order as consecutive blocks (n, D) and
        whose drives meet as ``graph`` says (``route.RouteGraph``; None: one drive): for a matcher that
        ``reads_route``, with the map's standing references (``motion.route_stands``), its graph and how far
        along it references stay alike (``likeness.reach``), read in one pass over the blocks; else itself."""
        if not self.reads_route:
            return self
        graph = None if graph is None or graph.simple else graph
        sample = LikenessSample()
        rows = sample.feed(blocks)
        route = None
        if self.still_threshold is None:
            for _ in rows:
                pass
        else:
            route = route_stands(rows, self.still_threshold, self.still_memory)
        return replace(self, route=route, graph=graph, reach=sample.reach(route))

    def run(self, sim: np.ndarray, k: int = 10, still: np.ndarray | None = None,
            search: StreamRows | None = None) -> Result:
        """Match every row of ``sim`` (Q, R); online matchers see the rows in order, past frames only, each
        with its motion cue from ``still`` (Q,) if given (``stillness``; offline matchers ignore it), and with
        ``search`` read them as it gives them (a map's index and coarse rows, ``map.search.StreamSearch``:
        what ``Localizer`` reads; None: the rows of ``sim``)."""
        sim = np.asarray(sim)
        if sim.ndim != 2 or 0 in sim.shape:
            raise ValueError(f"similarity matrix must be 2-D and non-empty, got shape {sim.shape}")
        if self.align is not None:
            return self.align(sim, k, **self.params)
        if search is not None:
            return run_rows(self.stream(sim.shape[1]), search.rows, sim.shape[0], sim.shape[1], k, still,
                            search.candidates)
        return run_online(self.stream(sim.shape[1]), sim, k, still)


def check_lost_line(min_confidence: float | None) -> float | None:
    """A lost threshold given by the user (``--min-confidence``), checked: VprError unless it is a finite
    number (None: not given)."""
    if min_confidence is not None and not math.isfinite(min_confidence):
        raise InputError("{opt.min_confidence} {v}: the lost threshold must be a finite number", v=min_confidence)
    return min_confidence


def check_target_precision(target: float | None) -> float | None:
    """A target precision given by the user (``--target-precision``), checked: VprError unless it lies in
    (0, 1) (None: not given)."""
    if target is not None and not (math.isfinite(target) and 0.0 < target < 1.0):
        raise InputError("{opt.target_precision} {v}: the target precision must lie between 0 and 1 (exclusive)",
                         v=target)
    return None if target is None else float(target)


WEAK_VIEW, NO_TRAJECTORY, AMBIGUOUS, LOCKED = "weak-view", "no-trajectory", "ambiguous", "locked"
OFF_MAP, SETTLING = "off-map", "settling"
# why a frame is lost (``lost_why``): ``stream``'s off-map, ambiguous, settling; ``stream-rules``' weak-view,
# no-trajectory, ambiguous
RULE_REASONS: tuple[str, ...] = (WEAK_VIEW, NO_TRAJECTORY, AMBIGUOUS)
FILTER_REASONS: tuple[str, ...] = (OFF_MAP, AMBIGUOUS, SETTLING)
LOST_WHY: tuple[str, ...] = (WEAK_VIEW, NO_TRAJECTORY, AMBIGUOUS, OFF_MAP, SETTLING)


def reasons_of(seen: Iterable[str | None]) -> tuple[str, ...]:
    """The reasons a matcher gives, from those its frames gave (``seen``): the filter's where any is one of
    its own (off-map, settling), else the rules'."""
    return FILTER_REASONS if {OFF_MAP, SETTLING} & set(seen) else RULE_REASONS


def lost_why(why: str | None, lost: bool) -> str | None:
    """A frame's reason for being lost, from its matcher's ``why()``: None where it is answered or the matcher
    gives no reason; the matcher's reason (``LOST_WHY``) where it is lost; "ambiguous" where the matcher holds
    it "locked" but a stricter lost line (``--min-confidence`` above the matcher's) calls it lost: the
    ``stream-rules`` score above 1 is the answer's uniqueness."""
    if not lost or why is None:
        return None
    return AMBIGUOUS if why == LOCKED else why


def is_lost(scores: np.ndarray | float, line: float | None) -> np.ndarray:
    """Scores (any shape) -> whether each answer is lost: below the lost threshold ``line`` (None: a matcher
    without a lost state, nothing is lost)."""
    scores = np.asarray(scores)
    return np.zeros(scores.shape, bool) if line is None else scores < line
