"""SIFT front ends (Lowe 2004) with OpenCV: on a dense grid, or on detected keypoints (padded, masked)."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from vpr_edge.features.base import Handcrafted, grey


@dataclass(frozen=True)
class DenseSift(Handcrafted):
    """128-dim SIFT descriptors at keypoints of diameter ``size`` px every ``step`` px on the grey image at
    width x height (no detection: the same grid in every image, N fixed)."""

    width: int = 128
    height: int = 96
    step: int = 16
    size: int = 16
    name: str = field(default="sift", init=False, repr=False)
    binary: bool = field(default=False, init=False, repr=False)
    dim: int = field(default=128, init=False, repr=False)

    def _grid(self) -> list[cv2.KeyPoint]:
        return [cv2.KeyPoint(float(x), float(y), float(self.size))
                for y in range(self.step // 2, self.height, self.step)
                for x in range(self.step // 2, self.width, self.step)]

    @property
    def n_local(self) -> int:
        return len(range(self.step // 2, self.height, self.step)) * len(range(self.step // 2, self.width, self.step))


    def describe(self) -> dict:
        return {"name": self.name, "params": {k: getattr(self, k) for k in ("width", "height", "step", "size")}}

    def local(self, images: Sequence[np.ndarray]) -> tuple[np.ndarray, None]:
        sift, grid = cv2.SIFT_create(), self._grid()
        out = np.zeros((len(images), len(grid), 128), np.float32)
        for i, im in enumerate(images):
            kps, desc = sift.compute(grey(im, (self.width, self.height)), grid)
            if desc is not None and len(kps) == len(grid):
                out[i] = desc
        return out, None


@dataclass(frozen=True)
class KeypointSift(Handcrafted):
    """SIFT on the ``max_keypoints`` strongest detected keypoints of the grey image at width x height;
    images with fewer are padded with zeros and the mask marks the real ones."""

    width: int = 256
    height: int = 192
    max_keypoints: int = 64
    name: str = field(default="sift-kp", init=False, repr=False)
    binary: bool = field(default=False, init=False, repr=False)
    dim: int = field(default=128, init=False, repr=False)
    n_local: None = field(default=None, init=False, repr=False)


    def describe(self) -> dict:
        return {"name": self.name, "params": {k: getattr(self, k) for k in ("width", "height", "max_keypoints")}}

    def local(self, images: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        sift = cv2.SIFT_create(nfeatures=self.max_keypoints)
        out = np.zeros((len(images), self.max_keypoints, 128), np.float32)
        mask = np.zeros((len(images), self.max_keypoints), bool)
        for i, im in enumerate(images):
            kps, desc = sift.detectAndCompute(grey(im, (self.width, self.height)), None)
            if desc is None:
                continue
            order = np.argsort([-k.response for k in kps], kind="stable")[: self.max_keypoints]
            out[i, : len(order)] = desc[order]
            mask[i, : len(order)] = True
        return out, mask
