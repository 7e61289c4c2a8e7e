"""The front-end contract: RGB images -> local descriptors (B, N, K), and what every front end shares.

A front end has ``name``, ``dim`` (K), ``n_local`` (N, or None when the number varies per image and a mask
marks the real ones), ``binary`` (descriptors are +-1 bits), ``local(images) -> (x, mask)``, ``describe()``
(JSON recorded in a map so that queries are described the same way), ``identity()`` (what else a map records:
the model's identity for ``cnn``), ``fingerprint`` (what a map checks), and a fitted part (``needs_fit``,
``fit``, ``select``: LDB's bit selection; the others fit nothing) and ``runs()`` (what runs, for the user:
for cnn the model file and its numeric form). ``colour`` is the colour order the model expects (cnn: RGB),
or None for a front end that reads grey; greyscale frames given to the former draw a warning.
``Handcrafted`` gives the defaults.
"""
from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence
from typing import Protocol, runtime_checkable

import numpy as np

from vpr_edge.errors import VprError


@runtime_checkable
class FrontEnd(Protocol):
    name: str
    binary: bool

    @property
    def is_global(self) -> bool:
        """One global descriptor an image (N = 1), stored as it is: encoding none, no codebook."""

    @property
    def dim(self) -> int:
        """K, the length of one local descriptor."""

    @property
    def n_local(self) -> int | None:
        """N, descriptors per image (None: varies, a mask marks the real ones)."""

    @property
    def fingerprint(self) -> str:
        """SHA-256 identifying the descriptors (the model file for cnn, the parameters else)."""

    @property
    def source_fingerprint(self) -> str | None:
        """For an int8 model, the fp32 model's fingerprint (a codebook fitted on that one fits); else None."""

    @property
    def needs_fit(self) -> bool:
        """True until ``fit`` has chosen the fitted part (LDB's bits) on the references."""

    def local(self, images: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray | None]:
        """RGB uint8 images (H, W, 3) -> descriptors (B, N, K) float32 and mask (B, N) bool or None."""

    def describe(self) -> dict:
        """{"name": ..., "params": {...}}: enough to rebuild this front end (``make_front_end``)."""

    def identity(self) -> dict:
        """What a map records beside ``describe()`` to refuse another front end ({} for handcrafted ones)."""

    def runs(self) -> dict:
        """What runs, for the user: {"name": ...}, and for cnn the model file and its numeric form with the
        reason (e.g. {"name": "cnn", "model": "X.int8.onnx", "form": "int8: AVX512-VNNI"})."""

    def fit(self, local: np.ndarray, seed: int = 0) -> "FrontEnd":
        """This front end fitted on the references' descriptors ``local`` (R, N, K) (itself if nothing to fit)."""

    def select(self, local: np.ndarray) -> np.ndarray:
        """Descriptors as ``local`` gave them before ``fit`` -> as the fitted front end gives them."""


class Handcrafted:
    """Defaults for front ends computed from pixels alone (no model): fingerprint from the parameters,
    nothing to fit. A base of the frozen dataclasses in this package."""

    source_fingerprint: str | None = None
    needs_fit: bool = False
    is_global: bool = False
    colour: str | None = None   # the colour a model expects (cnn: RGB); handcrafted front ends read grey

    def describe(self) -> dict:  # pragma: no cover - every subclass defines it
        raise NotImplementedError

    @property
    def fingerprint(self) -> str:
        return spec_fingerprint(self.describe())

    def identity(self) -> dict:
        return {}

    def runs(self) -> dict:
        return {"name": self.name}

    def fit(self, local: np.ndarray, seed: int = 0) -> "Handcrafted":
        return self

    def select(self, local: np.ndarray) -> np.ndarray:
        return local


def spec_fingerprint(spec: dict) -> str:
    """SHA-256 of a handcrafted front end's record (its name and parameters): what a map checks."""
    return hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()


def grey(rgb: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """RGB uint8 (H, W, 3) -> grey uint8 (height, width) at ``size`` = (width, height), area-averaged when
    shrinking, bilinear when enlarging."""
    import cv2

    g = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    interp = cv2.INTER_AREA if g.shape[1] >= size[0] else cv2.INTER_LINEAR
    return cv2.resize(g, size, interpolation=interp)


def check_finite(local: np.ndarray, names: Sequence[str], front: str) -> None:
    """VprError naming the first image of ``names`` whose descriptors in ``local`` (B, N, K) are not all
    finite (a model that gives NaN or infinity for some input), before it reaches a map or an answer."""
    bad = ~np.isfinite(local.reshape(len(local), -1)).all(axis=1)
    if bad.any():
        raise VprError(f"{names[int(np.argmax(bad))]}: the {front} front end gives NaN or infinite descriptors "
                       f"for this image (a model that does not take such input?)")
