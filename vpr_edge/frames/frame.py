"""One frame of a stream, whatever its source (a folder, a video, a camera, a ROS bag)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MIN_SIDE = 8  # pixels: below this an image cannot describe a place (a 1x1 "image" is a broken file)


@dataclass(frozen=True)
class Frame:
    """One frame of a stream: its position, a name for reports, the RGB image or the decode error, and its
    time in seconds (``stamp``: a video's presentation time, a live source's arrival time (Unix), a folder's
    from a timestamps file; None when unknown). A frame of a descriptor file has no image but its global
    ``descriptor`` (D,) float32 (``frames.descriptor_files``)."""

    index: int
    name: str
    image: np.ndarray | None
    error: str | None = None
    stamp: float | None = None
    descriptor: np.ndarray | None = None

    @property
    def readable(self) -> bool:
        """Whether it has something to encode (an image or a descriptor)."""
        return self.image is not None or self.descriptor is not None
