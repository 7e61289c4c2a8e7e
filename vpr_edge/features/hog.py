"""HOG front end (Dalal & Triggs 2005) with OpenCV's HOGDescriptor: each block a local descriptor."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field

import cv2
import numpy as np

from vpr_edge.features.base import Handcrafted, grey


@dataclass(frozen=True)
class Hog(Handcrafted):
    """Grey image resized to width x height; blocks of ``block`` px every ``stride`` px, cells of ``cell``
    px, ``bins`` orientation bins, L2-Hys per block (OpenCV's defaults). N = blocks, K = (block/cell)^2 bins."""

    width: int = 128
    height: int = 64
    cell: int = 8
    block: int = 16
    stride: int = 8
    bins: int = 9
    name: str = field(default="hog", init=False, repr=False)
    binary: bool = field(default=False, init=False, repr=False)

    @property
    def dim(self) -> int:
        return (self.block // self.cell) ** 2 * self.bins

    @property
    def n_local(self) -> int:
        return ((self.width - self.block) // self.stride + 1) * ((self.height - self.block) // self.stride + 1)


    def describe(self) -> dict:
        return {"name": self.name, "params": {k: v for k, v in asdict(self).items() if k not in ("name", "binary")}}

    def local(self, images: Sequence[np.ndarray]) -> tuple[np.ndarray, None]:
        hog = cv2.HOGDescriptor((self.width, self.height), (self.block, self.block), (self.stride, self.stride),
                                (self.cell, self.cell), self.bins)
        out = np.stack([hog.compute(grey(im, (self.width, self.height))) for im in images])
        return out.reshape(len(images), self.n_local, self.dim).astype(np.float32), None
