"""Localise a stream of frames against a map with any registered matcher (online: a result per frame as
it arrives; offline: results after the last frame)."""
from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass

import numpy as np

from vpr_edge.extract import FeatureExtractor
from vpr_edge.images import Frame
from vpr_edge.mapfile import PlaceMap
from vpr_edge.matchers import Matcher


@dataclass(frozen=True)
class Match:
    """One output line: the query frame, the matched reference (index -1 and name '' when lost) and a
    score (higher = more confident)."""

    frame_index: int
    frame: str
    ref_index: int
    ref: str
    score: float
    lost: bool


def encode_frames(frames: Iterable[Frame], place_map: PlaceMap, extractor: FeatureExtractor, batch_size: int,
                  on_skip: Callable[[Frame], None]) -> Iterator[tuple[Frame, np.ndarray]]:
    """Yield (frame, encoding (D,)) for each decodable frame, ``batch_size`` frames per model run;
    undecodable frames go to ``on_skip``."""
    pending: list[Frame] = []

    def flush() -> Iterator[tuple[Frame, np.ndarray]]:
        batch = np.stack([extractor.preprocess(f.image) for f in pending])
        yield from zip(pending, place_map.encode(extractor.local_features(batch)))
        pending.clear()

    for frame in frames:
        if frame.image is None:
            on_skip(frame)
            continue
        pending.append(frame)
        if len(pending) >= batch_size:
            yield from flush()
    if pending:
        yield from flush()


def localize(frames: Iterable[Frame], place_map: PlaceMap, extractor: FeatureExtractor, matcher: Matcher,
             batch_size: int = 1, min_confidence: float | None = None,
             on_skip: Callable[[Frame], None] = lambda f: None) -> Iterator[Match]:
    """Match every decodable frame to a reference of ``place_map`` with ``matcher``; a frame whose score is
    below ``min_confidence`` (default: the matcher's own; None and no default: never) is reported lost."""
    refs = place_map.encodings
    encoded = encode_frames(frames, place_map, extractor, batch_size, on_skip)
    threshold = matcher.min_confidence if min_confidence is None else min_confidence

    def line(frame: Frame, ref: int, score: float) -> Match:
        lost = threshold is not None and score < threshold
        return Match(frame.index, frame.name, -1 if lost else ref, "" if lost else place_map.names[ref], score,
                     lost)

    if matcher.online:
        online = matcher.stream(len(refs))
        for frame, enc in encoded:
            ref, score = online.update(refs @ enc)
            yield line(frame, ref, score)
        return
    pairs = list(encoded)
    if pairs:
        result = matcher.run(np.stack([e for _, e in pairs]) @ refs.T, k=1)
        for (frame, _), ref, score in zip(pairs, result.refs, result.scores):
            yield line(frame, int(ref), float(score))
