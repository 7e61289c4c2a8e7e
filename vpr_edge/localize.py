"""Localise a stream of frames against a map: streaming DTW, offline DTW or best single match."""
from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Literal

import numpy as np

from vpr_edge.extract import FeatureExtractor
from vpr_edge.images import Frame
from vpr_edge.mapfile import PlaceMap
from vpr_edge.match import StreamingDTW, best_match, dtw_align

Mode = Literal["stream", "dtw", "single"]
MODES: tuple[str, ...] = ("stream", "dtw", "single")


@dataclass(frozen=True)
class Match:
    """One output line: the query frame, the matched reference and a score (higher = more confident)."""

    frame_index: int
    frame: str
    ref_index: int
    ref: str
    score: float


def _encoded(frames: Iterable[Frame], place_map: PlaceMap, extractor: FeatureExtractor, batch_size: int,
             on_skip: Callable[[Frame], None]) -> Iterator[tuple[Frame, np.ndarray]]:
    """Yield (frame, encoding (D,)) for each decodable frame, ``batch_size`` frames per model run."""
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


def localize(frames: Iterable[Frame], place_map: PlaceMap, extractor: FeatureExtractor, mode: Mode = "stream",
             variant: str = "similarity", decay: float = 0.9, batch_size: int = 1, open_ends: bool = False,
             on_skip: Callable[[Frame], None] = lambda f: None) -> Iterator[Match]:
    """Match every decodable frame to a reference of ``place_map``.

    ``stream``: streaming DTW, one result per frame as it arrives, bounded memory. ``single``: best single
    match per frame. ``dtw``: offline DTW (``variant`` 'similarity' or 'distance'; ``open_ends`` for a query
    covering part of the route) over the whole sequence, results after the last frame. Undecodable frames
    are passed to ``on_skip`` and left out.
    """
    refs = place_map.encodings
    encoded = _encoded(frames, place_map, extractor, batch_size, on_skip)
    if mode == "stream":
        dtw = StreamingDTW(len(refs), decay)
        for frame, enc in encoded:
            ref, score = dtw.update(refs @ enc)
            yield Match(frame.index, frame.name, ref, place_map.names[ref], score)
    elif mode == "single":
        for frame, enc in encoded:
            ref, score = best_match((refs @ enc)[None])
            yield Match(frame.index, frame.name, int(ref[0]), place_map.names[int(ref[0])], float(score[0]))
    elif mode == "dtw":
        pairs = list(encoded)
        if not pairs:
            return
        result = dtw_align(np.stack([e for _, e in pairs]) @ refs.T, variant, open_ends)  # type: ignore[arg-type]
        for (frame, _), ref, score in zip(pairs, result.matches, result.scores):
            yield Match(frame.index, frame.name, int(ref), place_map.names[int(ref)], float(score))
    else:
        raise ValueError(f"unknown mode {mode!r}; choose from {MODES}")
