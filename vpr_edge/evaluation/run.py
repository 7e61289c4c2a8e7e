"""``evaluate``: one function from a source of frames (or similarities), ground truth and matchers to a report
per matcher. ``vpr-edge evaluate`` parses options and prints what this returns; the tools call it too."""
from __future__ import annotations

import os
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vpr_edge.calibration import Curve
from vpr_edge.encoders.standardise import STANDARDISE
from vpr_edge.errors import InputError, VprError
from vpr_edge.evaluation import sources
from vpr_edge.evaluation.scoring import ModeReport, evaluate_mode
from vpr_edge.evaluation.truth import Truth, one_view
from vpr_edge.features.choice import DEFAULT_PRECISION
from vpr_edge.matchers import (DEFAULT_MATCHER, MATCHERS, Matcher, check_lost_line, check_target_precision,
                               get_matcher)
from vpr_edge.matchers.constants import MEMORY
from vpr_edge.matchers.motion import route_stands
from vpr_edge.matchers.params import STREAM
from vpr_edge.matchers.route import RouteGraph
from vpr_edge.map import MapQuery, PlaceMap, load_map
from vpr_edge.index.coarse import CoarseSearch
from vpr_edge.map.search import FrameSearch, StreamSearch, coarse_search, uses_coarse
from vpr_edge.positions import Positions
from vpr_edge.threads import use_threads

PathLike = str | os.PathLike[str]


@dataclass(frozen=True)
class Source:
    """Where the (Q, R) similarities come from; exactly one of: ``similarity`` (a .npy matrix), ``map`` with
    ``queries`` (frames encoded by the map's chain), or ``pixels`` with ``refs`` and ``queries`` (SeqSLAM's
    front end, no map). ``model``, ``batch_size`` and ``threads`` apply to ``map``."""

    similarity: PathLike | None = None
    map: PathLike | None = None
    queries: PathLike | None = None
    refs: PathLike | None = None
    pixels: bool = False
    model: Path | None = None
    batch_size: int = 8
    threads: int = 0
    topic: str | None = None      # queries is a ROS bag / MCAP file: its image topic
    precision: str = DEFAULT_PRECISION   # the model's form (features.choice), with map
    standardise: bool = STANDARDISE      # with map: cosines of the standardised encodings (encoders.standardise)

    def check(self) -> None:
        """VprError unless exactly one source is complete (called before any work)."""
        if sum([self.similarity is not None, self.map is not None, self.pixels]) != 1:
            raise InputError("give one source: {opt.similarity} S.npy, or {opt.map} MAP {opt.queries} Q, or "
                             "{opt.pixels} {opt.refs} R {opt.queries} Q")
        if self.similarity is None and self.queries is None:
            raise InputError("{opt.queries} is needed with {opt.map} or {opt.pixels}")
        if self.pixels and self.refs is None:
            raise InputError("{opt.pixels} needs {opt.refs} (the reference folder)")

    @property
    def name(self) -> str:
        return str(self.queries or self.similarity)


@dataclass(frozen=True)
class Evaluation:
    """``reports`` per matcher name, over ``similarity`` (Q, R); ``n_mapped`` of the Q frames show a mapped
    place; ``encode_ms``: encoding time per frame (NaN for a similarity file)."""

    reports: dict[str, ModeReport]
    similarity: np.ndarray
    n_mapped: int
    tolerance: int
    encode_ms: float
    truth: np.ndarray | None = None           # (Q, T) the rows scored (frames that did not decode left out)
    positions: Positions | None = None        # the references', from a map built with positions
    front: dict | None = None                 # the model file run and its form, with a map


BASELINES = ("single", "seqslam-online")   # the plain matchers the default mode is measured against
# what evaluate runs without --modes: the default mode beside the baselines (three modes: a table a person reads)
DEFAULT_MODES = (DEFAULT_MATCHER, *BASELINES)
ALL_MODES = "all"   # the --modes word for every matcher that applies (``every_matcher``)


def default_matchers() -> dict[str, Matcher]:
    """What ``evaluate`` runs without ``--modes``: ``DEFAULT_MODES``."""
    return {name: get_matcher(name) for name in DEFAULT_MODES}


def every_matcher(source: Source, place_map: PlaceMap | None = None) -> dict[str, Matcher]:
    """What ``--modes all`` runs: every matcher over cosine similarities, and ``svm`` when the source is a map
    built with ``--svm`` (``place_map``: that map, if already open)."""
    chosen = {n: m for n, m in MATCHERS.items() if m.scores == "cosine"}
    if source.map is not None:
        if place_map is None:
            place_map = load_map(source.map, mmap=True)
        if place_map.svm is not None:
            chosen["svm"] = get_matcher("svm")
    return chosen


def matchers_named(modes: str | None, source: Source) -> dict[str, Matcher]:
    """The matchers a ``--modes`` value names (comma-separated; None: ``default_matchers``; the word ``all``:
    ``every_matcher``). InputError naming the option for an unknown name."""
    if modes is None:
        return default_matchers()
    chosen: dict[str, Matcher] = {}
    for name in (m.strip() for m in modes.split(",")):
        if name == ALL_MODES:
            chosen |= {n: m for n, m in every_matcher(source).items() if n not in chosen}
        elif name and name not in chosen:
            if name not in MATCHERS:
                raise InputError("{opt.modes}: unknown matcher {name!r}; choose from {names}, or " + ALL_MODES,
                                 name=name, names=", ".join(MATCHERS))
            chosen[name] = get_matcher(name)
    return chosen


def check_truth_fits(truth: np.ndarray, gt_shape: tuple[int, ...] | None, sim: np.ndarray, where: str) -> None:
    """VprError unless ``truth`` (Q, T) has a row per query of ``sim`` (Q, R) and names only its references."""
    if len(truth) != sim.shape[0]:
        raise VprError(f"{where}: ground truth has {len(truth)} rows but there are {sim.shape[0]} queries")
    check_truth_refs(truth, gt_shape, sim.shape[1], where, "the similarity matrix")


def check_truth_refs(truth: np.ndarray, gt_shape: tuple[int, ...] | None, n_refs: int, where: str,
                     against: str = "the map") -> None:
    """VprError unless ``truth`` (Q, T) names only references of ``against``, which has ``n_refs``, and a
    ground-truth matrix (``gt_shape`` (Q, R)) has that many columns: checked against a map before any frame
    is encoded."""
    if gt_shape is not None and gt_shape[1] != n_refs:
        raise VprError(f"{where}: ground-truth matrix has {gt_shape[1]} references, {against} {n_refs}")
    if truth.size and truth.max() >= n_refs:
        raise VprError(f"{where}: names reference {int(truth.max())} but {against} has only {n_refs} references "
                       f"(0 to {n_refs - 1})")


def map_same_view(blocks: Iterable[np.ndarray]) -> np.ndarray:
    """The map's references in route order, as consecutive blocks (n, D) -> (R,) bool: True where a reference
    shows the view of the one before it (its drive stood still, or saw nothing), by the default ``stream``
    motion cue (``motion.route_stands`` at the default ``still``): what ``truth.one_view`` reads."""
    return route_stands(blocks, STREAM["still"].default, MEMORY)


def stream_search(query: MapQuery | None, matcher: Matcher, encodings: np.ndarray | None, sim: np.ndarray,
                  coarse: list[CoarseSearch], standardise: bool = STANDARDISE) -> StreamSearch | None:
    """The rows ``matcher`` reads over the stream of ``encodings`` (Q, D) on ``query``'s map as ``Localizer``
    reads them (``map.search``: the index's candidates, coarse whole-route rows on a long map), exact rows from
    ``sim`` (Q, R); None where that is ``sim``'s rows alone (an offline matcher, no map, no index and no coarse
    rows). ``coarse``: the map's coarse search once made (empty: none yet), shared by the modes."""
    if query is None or encodings is None or not matcher.online:
        return None
    if uses_coarse(len(query.map.names), None, matcher.scores, matcher.searches_locally):
        if not coarse:
            coarse.append(coarse_search(query, True))
        rows = coarse[0]
    else:
        rows = None
    search = FrameSearch(query, matcher.scores, matcher.params.get("seek_frames", 1), rows, standardise)
    if search.index is None and search.coarse is None:
        return None
    return StreamSearch(search, encodings, sim)


def evaluate(source: Source, truth: Truth, matchers: dict[str, Matcher] | None = None, tolerance: int = 1,
             min_confidence: float | None = None, on_skip: sources.OnSkip = lambda frame: None,
             calibration: dict[str, Curve] | None = None, target_precision: float | None = None) -> Evaluation:
    """Run every matcher (default: ``default_matchers``, as ``vpr-edge evaluate`` without ``--modes``) on one
    similarity matrix from ``source`` and score it against ``truth`` (frames that do not decode go to
    ``on_skip`` and lose their ground-truth row); the modes with a curve in ``calibration`` (mode ->
    score-to-probability) also get its calibration error;
    ``target_precision``: the line of the modes whose score is a probability and of those with a curve (its
    drive's line), and where every mode's best line is read (``scoring.evaluate_mode``).
    VprError, before the work where it can be, for a bad source, ground truth or combination."""
    source.check()
    check_lost_line(min_confidence)
    check_target_precision(target_precision)
    query = None   # the map and its front end, opened once: the chain Localizer runs
    if source.map is not None:
        query = MapQuery(source.map, source.model, use_threads(source.threads), source.precision)
    chosen = default_matchers() if matchers is None else matchers
    if not chosen:
        raise InputError("{opt.modes} names no matcher")
    with_svm = any(m.scores == "svm" for m in chosen.values())
    if with_svm and query is None:
        raise InputError("mode svm needs {opt.map} (a map built with build-map {opt.svm})")
    rows, gt_shape = truth.load(query.map.positions if query is not None else None,
                                None if query is None else query.map.labels)
    if query is not None:   # the queries are the map's kind and the ground truth fits it, before any encoding
        if source.queries is not None:
            query.check_source(source.queries)
        check_truth_refs(rows, gt_shape, len(query.map.names), truth.name)
    if source.similarity is not None:
        sims = sources.from_file(source.similarity)
    elif source.pixels:
        sims = sources.from_pixels(source.refs, source.queries, len(rows), truth.name, on_skip, source.topic)
    else:
        sims = sources.from_map(query, source.queries, len(rows), truth.name, on_skip, source.batch_size, with_svm,
                                source.topic, source.standardise)
    if sims.kept is not None:
        if sims.kept.max() >= len(rows):
            raise VprError(f"{source.queries}: {sims.kept.max() + 1} frames but the ground truth {truth.name} has "
                           f"{len(rows)} rows")
        rows = rows[sims.kept]
    check_truth_fits(rows, gt_shape, sims.cosine, truth.name)
    by_kind = {"cosine": sims.cosine, "svm": sims.svm}
    same_view = None   # where the map shows one view (its drive stood still or saw nothing): truth.one_view
    if sims.references is not None:   # the map's own stops and drives, for matchers that read them
        graph = None if query is None else RouteGraph(*query.joins())
        chosen = {name: m.on_route(sims.references.in_order(), graph) for name, m in chosen.items()}
        same_view = next((m.route for m in chosen.values() if m.route is not None
                          and (m.still_threshold, m.still_memory) == (STREAM["still"].default, MEMORY)), None)
        if same_view is None:
            same_view = map_same_view(sims.references.in_order())
    drive = None if query is None or len(query.map.drives) < 2 else query.map.drives.of_each()
    coarse: list[CoarseSearch] = []   # the map's coarse search, made once for the modes that read it
    reports = {name: evaluate_mode(m, by_kind[m.scores], rows, tolerance, min_confidence, sims.positions,
                                   (calibration or {}).get(name),
                                   None if sims.encodings is None else m.cue(sims.encodings), drive,
                                   None if same_view is None else one_view(rows, same_view), target_precision,
                                   stream_search(query, m, sims.encodings, by_kind[m.scores], coarse,
                                                 source.standardise))
               for name, m in chosen.items()}
    return Evaluation(reports, sims.cosine, int((rows >= 0).any(axis=1).sum()), tolerance, sims.encode_ms, rows,
                      sims.positions, sims.front)
