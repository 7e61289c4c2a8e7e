"""A map opened for queries: the map and the front end its queries go through, opened once, and the chain
each query frame takes to the matcher's input (preprocess -> features -> encode -> scores). ``Localizer``,
``evaluate`` and the tools share it, so that every path encodes and scores a frame the same way."""
from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path

import numpy as np

from vpr_edge.errors import MapChanged, VprError
from vpr_edge.features import FrontEnd
from vpr_edge.features.base import check_finite
from vpr_edge.features.choice import DEFAULT_PRECISION
from vpr_edge.features.descriptors import GivenDescriptors
from vpr_edge.frames.descriptor_files import descriptor_dims, is_descriptor_file
from vpr_edge.frames.frame import Frame
from vpr_edge.map.front import map_front_end
from vpr_edge.map.io import load_map
from vpr_edge.map.model import PlaceMap


MMAP_MIN_BYTES = 64 << 20   # smaller maps are read into memory: no later rewrite of the file can pull them away


class MapQuery:
    """``path``'s map and its front end (``map_front_end``: ``model`` if given, else the map's own;
    ``precision`` its numeric form; ``ort_threads`` onnxruntime's threads, 0 = its default). A map of
    ``MMAP_MIN_BYTES`` or more stays memory-mapped (``mapped``), and ``check_unchanged`` tells whether its file
    was rewritten since; a smaller one is read into memory. VprError for a bad map or a model that does not
    fit it."""

    def __init__(self, path: str | os.PathLike[str], model: str | os.PathLike[str] | None = None,
                 ort_threads: int = 0, precision: str = DEFAULT_PRECISION) -> None:
        self.path = Path(path)
        self._opened = self._identity()
        self.mapped = self._opened is not None and self._opened[0] >= MMAP_MIN_BYTES
        self.map: PlaceMap = load_map(path, mmap=self.mapped)
        self.front: FrontEnd = map_front_end(self.map, path, Path(model) if model else None, ort_threads,
                                             precision)

    def _identity(self) -> tuple[int, int, int] | None:
        """(size, modification time ns, inode) of the map file (None: it cannot be read; load_map says why)."""
        try:
            st = os.stat(self.path)
        except OSError:
            return None
        return st.st_size, st.st_mtime_ns, st.st_ino

    def check_unchanged(self) -> None:
        """``MapChanged`` naming the map if a memory-mapped map's file was rewritten or replaced since it was
        opened (reading its pages then would be reading another map, or crash the process on a truncated
        one); nothing for a map in memory. One ``stat`` a call."""
        if self.mapped and self._identity() != self._opened:
            raise MapChanged(f"{self.path}: the map file changed while in use (rewritten in place?); stopped, "
                             f"the results so far kept: run again with the new map")

    @property
    def names(self) -> list[str]:
        """Reference image names, in map order (index = reference index)."""
        return self.map.names

    @property
    def takes_descriptors(self) -> bool:
        """Whether the map's places are global descriptors computed elsewhere (queries: descriptor files)."""
        return isinstance(self.front, GivenDescriptors)

    def check_source(self, source: str | os.PathLike[str]) -> None:
        """VprError naming ``source`` when it is the other kind of input than the map's places: a descriptor
        file (``.npy``, ``.h5``) for a map of images, images for a map of descriptors, or descriptors of
        another dimension (checked before the work)."""
        if is_descriptor_file(source) and not self.takes_descriptors:
            raise VprError(f"{source}: global descriptors given, but the map {self.path} describes images with "
                           f"its {self.front.name} front end")
        if self.takes_descriptors and not is_descriptor_file(source):
            raise VprError(f"{source}: the map {self.path} holds global descriptors of {self.front.dim} dims: "
                           f"give a descriptor file (.npy, .h5) of the same network, not images")
        if self.takes_descriptors:
            dims = descriptor_dims(source)   # the header: the values are checked where the frames are read
            if dims != self.front.dim:
                raise VprError(f"{source}: descriptors of {dims} dims, but the map's places are descriptors of "
                               f"{self.front.dim} dims")

    def encode(self, images: Sequence[np.ndarray], names: Sequence[str] | None = None) -> np.ndarray:
        """RGB uint8 images (H, W, 3) -> encodings (B, D) float32 comparable with the map's (one model run);
        VprError naming the image (``names``, else its place in the batch) whose descriptors are not finite."""
        local, mask = self.front.local(images)
        check_finite(local, names or [f"image {i} of the batch" for i in range(len(images))], self.front.name)
        return self.map.encode(local, mask)

    def encode_descriptors(self, descriptors: np.ndarray, source: str = "") -> np.ndarray:
        """Global descriptors (B, D) of a map of descriptors -> encodings (B, D) float32 (L2-normalised)."""
        if not self.takes_descriptors:
            raise VprError(f"{source or 'descriptors'}: global descriptors given, but the map {self.path} "
                           f"describes images with its {self.front.name} front end")
        return self.map.encode(self.front.given(descriptors, source))

    def encode_frames(self, frames: Iterable[Frame], batch_size: int,
                      on_skip: Callable[[Frame], None]) -> Iterator[tuple[Frame, np.ndarray]]:
        """Yield (frame, encoding (D,)) for each readable frame (an image, or a descriptor file's vector),
        ``batch_size`` frames per model run; undecodable frames go to ``on_skip``."""
        pending: list[Frame] = []

        def flush() -> Iterator[tuple[Frame, np.ndarray]]:
            if pending[0].descriptor is not None:
                encoded = self.encode_descriptors(np.stack([f.descriptor for f in pending]), pending[0].name)
            else:
                encoded = self.encode([f.image for f in pending], [f.name for f in pending])
            yield from zip(pending, encoded)
            pending.clear()

        for frame in frames:
            if not frame.readable:
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

    def joins(self) -> tuple[int, np.ndarray, list[tuple[np.ndarray, np.ndarray]]]:
        """The map's places as drives for a matcher (``matchers.route.RouteGraph``'s arguments): the number of
        places, each drive's first place, and where drives meet (``Drives.junctions``)."""
        return len(self.map.names), self.map.drives.starts, self.map.drives.junctions(self.map.positions)

    def references(self) -> Iterator[np.ndarray]:
        """The map's stored encodings in route order, a block at a time (``Matcher.on_route``)."""
        return self.map.stored.in_order()

    def runs(self) -> dict:
        """What runs: the front end's name, and for cnn the model file and its form with the reason."""
        return self.front.runs()
