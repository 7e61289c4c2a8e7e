"""SeqSLAM's front end (Milford & Wyeth 2012): grey images downsampled to 64x32, every 8x8 patch normalised.

``pixel_descriptor`` is one image as a flat vector (what ``evaluate --features pixels`` compares by the mean
absolute difference); ``Patches`` gives the same values as 32 local 64-dim descriptors for the encoders."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from vpr_edge.features.base import Handcrafted, grey

SIZE = (64, 32)     # width, height (SeqSLAM's Nordland setting)
PATCH = 8           # patch normalisation: PATCH x PATCH blocks


def pixel_descriptor(rgb: np.ndarray, size: tuple[int, int] = SIZE, patch: int = PATCH) -> np.ndarray:
    """RGB uint8 (H, W, 3) -> float32 (h*w,): grey, resized (area), every patch x patch block z-scored."""
    x = grey(rgb, size).astype(np.float32)
    h, w = size[1] // patch, size[0] // patch
    blocks = x[: h * patch, : w * patch].reshape(h, patch, w, patch)
    mean = blocks.mean(axis=(1, 3), keepdims=True)
    std = blocks.std(axis=(1, 3), keepdims=True)
    return ((blocks - mean) / np.maximum(std, 1e-3)).reshape(-1).astype(np.float32)


@dataclass(frozen=True)
class Patches(Handcrafted):
    """N = (64/8) * (32/8) = 32 patches, K = 64 normalised grey values each."""

    width: int = SIZE[0]
    height: int = SIZE[1]
    patch: int = PATCH
    name: str = field(default="pixels", init=False, repr=False)
    binary: bool = field(default=False, init=False, repr=False)

    @property
    def dim(self) -> int:
        return self.patch * self.patch

    @property
    def n_local(self) -> int:
        return (self.width // self.patch) * (self.height // self.patch)


    def describe(self) -> dict:
        return {"name": self.name, "params": {"width": self.width, "height": self.height, "patch": self.patch}}

    def local(self, images: Sequence[np.ndarray]) -> tuple[np.ndarray, None]:
        flat = np.stack([pixel_descriptor(im, (self.width, self.height), self.patch) for im in images])
        h, w, p = self.height // self.patch, self.width // self.patch, self.patch
        blocks = flat.reshape(len(images), h, p, w, p).transpose(0, 1, 3, 2, 4)   # (B, h, w, p, p)
        return np.ascontiguousarray(blocks.reshape(len(images), h * w, p * p)), None
