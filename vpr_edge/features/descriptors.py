"""``descriptors``: the front end of a map built from global descriptors computed elsewhere (a NetVLAD,
CosPlace, EigenPlaces or MixVPR network; ``frames.descriptor_files`` reads them). Each place is one D-dim vector,
its own single local descriptor (N = 1), encoded as it is (L2-normalised: encoding ``none``); queries must
be descriptors of the same D from the same network, never images."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from vpr_edge.errors import VprError
from vpr_edge.features.base import Handcrafted


@dataclass(frozen=True)
class GivenDescriptors(Handcrafted):
    """Global descriptors of ``dims`` dimensions, given: what the map records so that its queries are the same."""

    dims: int
    name: str = field(default="descriptors", init=False, repr=False)
    binary: bool = field(default=False, init=False, repr=False)
    is_global: bool = field(default=True, init=False, repr=False)

    def __post_init__(self) -> None:
        if not (isinstance(self.dims, int) and self.dims > 0):
            raise VprError(f"front end descriptors: dims must be a positive integer, got {self.dims!r}")

    @property
    def dim(self) -> int:
        return self.dims

    @property
    def n_local(self) -> int:
        return 1

    def describe(self) -> dict:
        return {"name": self.name, "params": {"dims": self.dims}}

    def local(self, images: Sequence[np.ndarray]) -> tuple[np.ndarray, None]:
        raise VprError(f"this map's places are descriptors of {self.dims} dims computed elsewhere: give a "
                       f"descriptor file (.npy, .h5) of the same network, not images")

    def given(self, descriptors: np.ndarray, source: str = "") -> np.ndarray:
        """Descriptors (B, D) -> (B, 1, D) float32, this front end's local descriptors; VprError naming
        ``source`` for another D."""
        x = np.asarray(descriptors, np.float32)
        if x.ndim != 2 or x.shape[1] != self.dims:
            raise VprError(f"{source + ': ' if source else ''}descriptors of {x.shape[-1]} dims, but the map's "
                           f"places are descriptors of {self.dims} dims")
        return x[:, None, :]
