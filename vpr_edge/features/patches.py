"""SeqSLAM's front end as local descriptors: grey 64x32, each 8x8 patch normalised (``vpr_edge.pixels``)."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from vpr_edge.features import spec_fingerprint
from vpr_edge.pixels import PATCH, SIZE, pixel_descriptor


@dataclass(frozen=True)
class Patches:
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

    @property
    def fingerprint(self) -> str:
        return spec_fingerprint(self.describe())

    def describe(self) -> dict:
        return {"name": self.name, "params": {"width": self.width, "height": self.height, "patch": self.patch}}

    def local(self, images: Sequence[np.ndarray]) -> tuple[np.ndarray, None]:
        flat = np.stack([pixel_descriptor(im, (self.width, self.height), self.patch) for im in images])
        h, w, p = self.height // self.patch, self.width // self.patch, self.patch
        blocks = flat.reshape(len(images), h, p, w, p).transpose(0, 1, 3, 2, 4)   # (B, h, w, p, p)
        return np.ascontiguousarray(blocks.reshape(len(images), h * w, p * p)), None
