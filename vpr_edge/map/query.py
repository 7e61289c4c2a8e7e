"""A map opened for queries: the map and the front end its queries go through, opened once, and the chain
each query frame takes to the matcher's input (preprocess -> features -> encode -> scores). ``Localizer``,
``evaluate`` and the tools share it, so that every path encodes and scores a frame the same way."""
from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path

import numpy as np

from vpr_edge.features import FrontEnd
from vpr_edge.features.choice import DEFAULT_PRECISION
from vpr_edge.frames.images import Frame
from vpr_edge.map.front import map_front_end
from vpr_edge.map.io import load_map
from vpr_edge.map.model import PlaceMap


class MapQuery:
    """``path``'s map (memory-mapped) and its front end (``map_front_end``: ``model`` if given, else the
    map's own; ``precision`` its numeric form; ``ort_threads`` onnxruntime's threads, 0 = its default).
    VprError for a bad map or a model that does not fit it."""

    def __init__(self, path: str | os.PathLike[str], model: str | os.PathLike[str] | None = None,
                 ort_threads: int = 0, precision: str = DEFAULT_PRECISION) -> None:
        self.path = Path(path)
        self.map: PlaceMap = load_map(path, mmap=True)
        self.front: FrontEnd = map_front_end(self.map, path, Path(model) if model else None, ort_threads,
                                             precision)

    @property
    def names(self) -> list[str]:
        """Reference image names, in map order (index = reference index)."""
        return self.map.names

    def encode(self, images: Sequence[np.ndarray]) -> np.ndarray:
        """RGB uint8 images (H, W, 3) -> encodings (B, D) float32 comparable with the map's (one model run)."""
        return self.map.encode(*self.front.local(images))

    def encode_frames(self, frames: Iterable[Frame], batch_size: int,
                      on_skip: Callable[[Frame], None]) -> Iterator[tuple[Frame, np.ndarray]]:
        """Yield (frame, encoding (D,)) for each decodable frame, ``batch_size`` frames per model run;
        undecodable frames go to ``on_skip``."""
        pending: list[Frame] = []

        def flush() -> Iterator[tuple[Frame, np.ndarray]]:
            yield from zip(pending, self.encode([f.image for f in pending]))
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

    def scores(self, encodings: np.ndarray, kind: str = "cosine", refs: np.ndarray | None = None) -> np.ndarray:
        """Encodings (B, D) -> what a matcher compares, (B, R): ``cosine`` similarities or ``svm`` decision
        values (``PlaceMap.scores``), to the references ``refs`` only if given."""
        return self.map.scores(encodings, kind, refs)

    def references(self) -> Iterator[np.ndarray]:
        """The map's stored encodings in route order, a block at a time (``Matcher.on_route``)."""
        return self.map.stored.in_order()

    def runs(self) -> dict:
        """What runs: the front end's name, and for cnn the model file and its form with the reason."""
        return self.front.runs()
