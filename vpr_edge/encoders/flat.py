"""``none``: no encoding. The front end's local descriptors in grid order, flattened and L2-normalised (the
thesis's "without FV": a conv tap's W x H x K map as one vector; a handcrafted descriptor as it is)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from vpr_edge.encoders.base import Encoder, FitSettings, power_l2
from vpr_edge.errors import VprError


@dataclass(frozen=True)
class Flatten(Encoder):
    """(B, N, K) -> (B, N*K) unit rows. Needs a fixed grid (the same N for every image); masked cells count
    as zeros."""

    name: ClassVar[str] = "none"
    summary: ClassVar[str] = "no encoding: local descriptors flattened in grid order, L2-normalised"
    needs_fit: ClassVar[bool] = False
    input_dim: int
    n_local: int
    pca: None = None

    @property
    def dim(self) -> int:
        return self.n_local * self.input_dim

    def params(self) -> dict:
        return {"n_local": self.n_local}

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], params: dict, input_dim: int) -> "Flatten":
        return cls(input_dim, int(params["n_local"]))

    @classmethod
    def fit(cls, x: np.ndarray, s: FitSettings, input_dim: int, local: np.ndarray | None = None,
            mask: np.ndarray | None = None, n_local: int | None = None) -> "Flatten":
        if n_local is None:
            raise VprError("encoding none needs a front end with a fixed grid of descriptors; this one detects "
                           "keypoints (a varying number per image): choose bow, vlad, fv or ifv")
        return cls(input_dim, n_local)

    def transform(self, x: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
        self.check(x)
        if x.shape[1] != self.n_local:
            raise VprError(f"encoding none expects {self.n_local} descriptors per image, got {x.shape[1]}")
        x = np.asarray(x, np.float64)
        if mask is not None:   # masked cells of a fixed grid (a padded frame's border) count as zeros
            x = x * np.asarray(mask, bool)[..., None]
        return power_l2(x.reshape(len(x), -1))
