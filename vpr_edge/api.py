"""The per-frame chain, written once: preprocess -> features -> encode -> similarity -> matcher.

``Localizer`` is what a robot's camera callback, the CLI and the tools use::

    from vpr_edge import Localizer

    loc = Localizer("route.map.npz", threads=2)        # opens the map and its model once
    def on_frame(rgb):                                 # RGB uint8 (H, W, 3), e.g. from the camera driver
        m = loc.push(rgb)
        if not m.lost:
            print(m.ref_index, m.ref, m.score)
"""
from __future__ import annotations

import math
import os
import threading
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np
# np.unique imports numpy.ma on its first call (numpy 2): imported with the chain, so that a vehicle's first
# frame does not pay for it (15 ms, a whole-route frame's cost again)
import numpy.ma  # noqa: F401

from vpr_edge.encoders.standardise import STANDARDISE
from vpr_edge.errors import InputError, VprError, printable
from vpr_edge.features import FrontEnd
from vpr_edge.features.choice import DEFAULT_PRECISION
from vpr_edge.frames.images import MIN_SIDE, Frame
from vpr_edge.map import MapQuery, PlaceMap
from vpr_edge.map.search import FrameSearch, coarse_search, uses_coarse
from vpr_edge.matchers import DEFAULT_MATCHER, Matcher, get_matcher, is_lost, lost_why, step
from vpr_edge.matchers.route import RouteGraph
from vpr_edge.threads import use_threads


RESULTS_SCHEMA = 5   # the output line (docs/formats.md, docs/results-line.schema.json); 5: confidence from the
#                     mode's own probability without a calibration; 4: lost_why; 3: drive; 2: stamp, position


@dataclass(frozen=True)
class Match:
    """One output line (``RESULTS_SCHEMA``): the query frame (its index in the stream, name and time in seconds
    or None), the matched reference (index, image name and the name of its drive; None when lost), its place when the map has
    positions (``x``/``y`` metres or ``lat``/``lon`` degrees, the other pair None; ``heading`` degrees or None;
    ``along_m``, metres along its drive from the drive's first reference; all None when lost or without
    positions),
    interpolated between references where the matcher resolves finer than one reference, a score (higher =
    more confident; its meaning per mode: docs/matchers.md), the ``confidence`` (the probability that the
    answer is right: from a calibration of the mode where one is given, else the mode's own where it models
    one, ``stream``; None without either), the lost flag and, for a lost frame of a mode that says so, why it
    is lost (``matchers.LOST_WHY``: off-map, ambiguous, settling; ``stream-rules``: weak-view, no-trajectory,
    ambiguous; else None)."""

    frame_index: int
    frame: str
    ref_index: int | None
    ref: str | None
    score: float
    lost: bool
    stamp: float | None = None
    confidence: float | None = None
    x: float | None = None
    y: float | None = None
    lat: float | None = None
    lon: float | None = None
    heading: float | None = None
    along_m: float | None = None
    drive: str | None = None
    lost_why: str | None = None

    def fields(self) -> dict:
        """The line as a dict in the schema's order (JSON lines; CSV writes None as an empty cell); a file
        name whose bytes are not UTF-8 with those bytes as ``\\xNN`` (``errors.printable``)."""
        line = {k: getattr(self, k) for k in FIELDS}
        for k in ("frame", "ref", "drive"):
            if line[k] is not None:
                line[k] = printable(line[k])
        return line


FIELDS = ("frame_index", "frame", "stamp", "ref_index", "ref", "drive", "x", "y", "lat", "lon", "heading", "along_m",
          "score", "confidence", "lost", "lost_why")


class Localizer:
    """A map, its model and a matcher, ready for frames.

    ``mode`` names a registered matcher (``vpr_edge.matchers.MATCHERS``), ``params`` overrides its
    parameters, ``min_confidence`` its lost threshold (default: the matcher's own); ``target_precision`` the
    line of a matcher whose score is the probability that its answer is right (``stream``; for another
    mode, VprError: it sets no line there) or, with a ``calibration`` (``evaluate --save-calibration`` on a
    labelled drive), of any mode: the lowest score whose answers at least as high were right that often on
    the drive (``calibration.Curve.line``; ``threshold`` is the line drawn, ``drive_line`` whether it is the
    drive's). ``precision``: the model's form (``features.choice``: auto runs
    its int8 form where the CPU has int8 dot products; fp32; int8). ``threads`` > 0 sets
    onnxruntime's threads and, process-wide, NumPy's BLAS pool to that count (0: one per core for both;
    None: onnxruntime's default, BLAS untouched). ``coarse``: a local-search matcher's whole-route frames use
    ``coarse.CoarseSearch`` (signs, exact values for the best candidates); None = on maps of at least
    ``COARSE_MIN_REFS`` references. ``standardise``: compare standardised encodings (``encoders.standardise``:
    each traversal's own mean taken away; ``reset`` forgets the stream's mean too). Construction is
    thread-safe (nothing global but the BLAS limit); ``push`` may be called from any thread, one frame at a time (a lock orders them). Each frame
    is matched with its motion cue (its encoding's likeness to the last frame that moved, against the stream's
    typical moving step: ``matchers.MotionCue``),
    so frames of one stream must be pushed in order; ``reset`` starts a new stream.
    Raises VprError for a bad map or model, ValueError for an unknown mode or parameter.
    """

    def __init__(self, map_path: str | os.PathLike[str], *, model: str | os.PathLike[str] | None = None,
                 mode: str = DEFAULT_MATCHER, params: dict | None = None, min_confidence: float | None = None,
                 threads: int | None = None, coarse: bool | None = None,
                 calibration: str | os.PathLike[str] | None = None, precision: str = DEFAULT_PRECISION,
                 target_precision: float | None = None, standardise: bool = STANDARDISE) -> None:
        self.matcher: Matcher = get_matcher(mode).with_params(**(params or {}))
        # checked before the map opens; a calibration's line (its labelled drive's) sets a target precision's
        self._calibration = None
        if calibration is not None:
            from vpr_edge.calibration import load

            self._calibration = load(calibration, self.matcher.name)
        line = None if self._calibration is None else self._calibration.target_line()
        self.threshold = self.matcher.lost_line(min_confidence, target_precision, live=True, line=line)
        # whether that line is the labelled drive's (``Matcher.lost_line``: a given min_confidence comes first)
        self.drive_line = line is not None and target_precision is not None and min_confidence is None
        if self.threshold is not None and math.isinf(self.threshold):   # the drive does not show the target
            raise InputError("{opt.target_precision} {v}: {path}, the labelled drive, does not show that precision "
                             "for mode {name} (every answer would be lost): label a longer drive, or ask for less",
                             v=target_precision, path=calibration, name=self.matcher.name)
        ort_threads = 0 if threads is None else use_threads(threads)
        self.query = MapQuery(map_path, model, ort_threads, precision)   # the map and its front end, once
        self.map.check_scores(self.matcher.scores, map_path)
        # where the map's drives stood, where they start and where they meet
        self.matcher = self.matcher.on_route(self.query.references(), RouteGraph(*self.query.joins()))
        self._online = self.matcher.stream(len(self.map.names)) if self.matcher.online else None
        # what each frame reads from the map: the rows asked for, coarse whole-route rows on a long map, the
        # index's candidates (``map.search``: evaluate runs the same)
        wanted = uses_coarse(len(self.map.names), coarse, self.matcher.scores,
                             self._online is not None and self._online.searches_locally)
        self._search = FrameSearch(self.query, self.matcher.scores, self.matcher.params.get("seek_frames", 1),
                                   coarse_search(self.query, wanted), standardise)
        self._lock = threading.Lock()
        self._count = 0
        self._cue = self.matcher.motion_cue()   # each frame's likeness to the last that moved

    @property
    def map(self) -> PlaceMap:
        """The map (``MapQuery.map``)."""
        return self.query.map

    @property
    def front(self) -> FrontEnd:
        """The front end its frames go through (``MapQuery.front``)."""
        return self.query.front

    @property
    def front_description(self) -> dict:
        """The front end run: its name, and for cnn the model file and its form with the reason
        (``features.choice``), e.g. {"name": "cnn", "model": "X.int8.onnx", "form": "int8: AVX512-VNNI"}."""
        return self.query.runs()

    @property
    def names(self) -> list[str]:
        """Reference image names, in map order (index = ``ref_index``)."""
        return self.query.names

    def encode(self, images: Sequence[np.ndarray]) -> np.ndarray:
        """RGB uint8 images (H, W, 3) -> encodings (B, D) float32, comparable with the map's by dot product."""
        return self.query.encode(images)

    def similarity(self, encodings: np.ndarray, refs: np.ndarray | None = None) -> np.ndarray:
        """Encodings (B, D) -> what the matcher compares, (B, R): cosine similarities to every reference, or
        for mode svm the places' decision values; to the references ``refs`` (int array) only, if
        given."""
        return self.query.scores(encodings, self.matcher.scores, refs)

    def _step(self, enc: np.ndarray) -> tuple[int, float, float | None, str | None, float | None]:
        """Match one encoding (D,), with its motion cue (its likeness to the encoding of the last frame that
        moved, ``matchers.MotionCue``): only the similarities the matcher asks for are computed (a local search
        around a locked position reads a window of the map, not all of it; with ``coarse``, a whole-route
        frame reads the signs and the best candidates; on a map with an index, a whole-route frame searches
        around the index's candidates instead, ``index.ivf``)."""
        self.query.check_unchanged()   # a memory-mapped map rewritten under us: stop before reading it
        self._search.push(enc)
        ref, score = step(self._online, self._search.rows, self._cue(enc), self._search.candidates())
        return ref, score, self._online.position(), self._online.why(), self._online.probability()

    def _line(self, index: int, name: str, ref: int, score: float, stamp: float | None = None,
              where: float | None = None, why: str | None = None, probability: float | None = None) -> Match:
        """The output line of a frame answered ``ref`` (at fractional reference ``where`` if the matcher
        resolves finer) with ``score``; ``why``: the matcher's ``why()`` for the frame (None: it gives none);
        ``probability``: the matcher's own probability that the answer is right (None: it models none)."""
        lost = bool(is_lost(score, self.threshold))
        if lost:
            return Match(index, name, None, None, score, True, stamp, lost_why=lost_why(why, True))
        confidence = probability if self._calibration is None else self._calibration(score)
        place: dict = {}
        if self.map.positions is not None:
            coords, heading, along = self.map.place_at(ref if where is None else where)
            keys = ("lat", "lon") if self.map.positions.geo else ("x", "y")
            place = {keys[0]: float(coords[0]), keys[1]: float(coords[1]), "along_m": along,
                     "heading": None if heading != heading else heading}
        return Match(index, name, ref, self.map.names[ref], score, False, stamp, confidence, **place,
                     drive=self.map.drives.of_ref(ref).name)

    def _check_online(self) -> None:
        """ValueError unless the mode matches frame by frame (``push`` and ``push_encoding``)."""
        if self._online is None:
            raise ValueError(f"mode {self.matcher.name} is offline (it needs the whole sequence): use run()")

    def push(self, rgb: np.ndarray, name: str = "", stamp: float | None = None) -> Match:
        """Localise the next frame of the stream (RGB uint8 (H, W, 3), taken at ``stamp`` seconds, which the
        answer carries); online modes only."""
        self._check_online()
        image = np.asarray(rgb)
        if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8 or min(image.shape[:2]) < MIN_SIDE:
            raise VprError(f"frame must be RGB uint8 (H, W, 3) of at least {MIN_SIDE}x{MIN_SIDE} pixels, got "
                           f"{image.dtype} {image.shape}")
        return self.push_encoding(self.encode([image])[0], name, stamp)

    def push_encoding(self, encoding: np.ndarray, name: str = "", stamp: float | None = None) -> Match:
        """``push`` for a frame already encoded (``encode``; (D,) float): its motion cue, the similarities the
        matcher asks for, the matcher's update and the output line; online modes only."""
        self._check_online()
        with self._lock:
            ref, score, where, why, probability = self._step(np.asarray(encoding, np.float32))
            self._count += 1
            return self._line(self._count - 1, name, ref, score, stamp, where, why, probability)

    def run(self, frames: Iterable[Frame], batch_size: int = 1,
            on_skip: Callable[[Frame], None] = lambda f: None) -> Iterator[Match]:
        """Localise a stream of frames (``images.open_stream``): online modes yield a match per frame as it
        is encoded (``batch_size`` frames per model run); offline modes after the last frame. Undecodable
        frames go to ``on_skip``."""
        return (match for _, match in self.answers(frames, batch_size, on_skip))

    def answers(self, frames: Iterable[Frame], batch_size: int = 1,
                on_skip: Callable[[Frame], None] = lambda f: None) -> Iterator[tuple[Frame, Match]]:
        """``run``, each match with the frame it answers (for outputs that show the frame:
        ``outputs.sink.ResultSink``)."""
        encoded = self.query.encode_frames(frames, batch_size, on_skip)
        if self._online is not None:
            for frame, enc in encoded:
                with self._lock:
                    ref, score, where, why, probability = self._step(enc)
                yield frame, self._line(frame.index, frame.name, ref, score, frame.stamp, where, why, probability)
            return
        pairs = list(encoded)
        if pairs:
            result = self.matcher.run(self.similarity(np.stack([e for _, e in pairs])), k=1)
            for (frame, _), ref, score in zip(pairs, result.refs, result.scores):
                yield frame, self._line(frame.index, frame.name, int(ref), float(score), frame.stamp)

    def reset(self) -> None:
        """Forget the stream (a new drive): the matcher starts again from no hypothesis."""
        with self._lock:
            if self._online is not None:
                self._online.reset()
            self._count = 0
            self._cue.reset()
            self._search.reset()
