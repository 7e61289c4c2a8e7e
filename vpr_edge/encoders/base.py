"""The encoder contract and what every encoder shares: optional PCA, masks, power and L2 normalisation.

An encoder turns local descriptors ``x`` (B, N, K) float32 -> encodings (B, D) float32 with unit L2 norm
(maps compare them by cosine, i.e. by dot product). ``mask`` (B, N) bool marks the real descriptors when
a front end yields a varying number per image (detected keypoints), padded to N; None means all are real.
Fitted state is plain arrays (``to_arrays``) plus JSON parameters (``params``): nothing is pickled.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from vpr_edge.errors import VprError
from vpr_edge.files.npz import write_npz

CODEBOOK_SCHEMA = 2        # 2: any encoder (meta "encoding"); 1: the IFV's PCA + GMM only
READS_CODEBOOK = (1, 2)


# The default codebook: 41 GMM components over local descriptors reduced to 24 whitened PCA dims, a
# 2 x 41 x 24 = 1,968-dim IFV (1,972 bytes a place as int8). Chosen on nordland-dev's derived streams among
# maps of at most 2,000 bytes a place, reported on Corridor too (docs/decisions.md, "The codebook").
DEFAULT_COMPONENTS = 41
DEFAULT_PCA_DIM = 24


PCA_AUTO = "auto"   # FitSettings.pca_dim: DEFAULT_PCA_DIM for descriptors of more dims that are not binary


@dataclass(frozen=True)
class FitSettings:
    """How to fit an encoder on reference descriptors: build-map's options, whose defaults these are (the
    library's ``build_map`` and the CLI make the same map)."""

    n_components: int = DEFAULT_COMPONENTS   # GMM components (fv, ifv) or visual words / centres (bow, vlad)
    pca_dim: int | None | str = PCA_AUTO     # PCA before the codebook (None: descriptors as they are; PCA_AUTO:
                                             # ``for_descriptors`` decides)
    whiten: bool = True
    alpha: float = 0.5            # signed power normalisation exponent (ifv, vlad); 1 = off
    max_descriptors: int = 30_000
    iterations: int = 20          # EM / k-means iterations at most (docs/decisions.md, "Tried and not taken")
    seed: int = 0
    tfidf: bool = False           # bow: weight words by inverse document frequency over the references

    def for_descriptors(self, dim: int, binary: bool) -> "FitSettings":
        """These settings for descriptors of ``dim`` dims (``binary``: ±1 bits, which PCA would not
        keep): ``PCA_AUTO`` becomes ``DEFAULT_PCA_DIM`` where the descriptors have more dims, else None."""
        if self.pca_dim != PCA_AUTO:
            return self
        return replace(self, pca_dim=DEFAULT_PCA_DIM if not binary and dim > DEFAULT_PCA_DIM else None)


@dataclass(frozen=True)
class Pca:
    """Projection x -> ((x - mean) @ components.T) / scale. mean (D,), components (K, D), scale (K,)."""

    mean: np.ndarray
    components: np.ndarray
    scale: np.ndarray

    def project(self, x: np.ndarray) -> np.ndarray:
        """(..., D) -> (..., K) float32."""
        return ((x - self.mean) @ self.components.T / self.scale).astype(np.float32, copy=False)

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {"pca_mean": self.mean, "pca_components": self.components, "pca_scale": self.scale}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], input_dim: int) -> "Pca | None":
        """The PCA stored in ``arrays`` (None if there is none); ValueError if its shapes disagree."""
        if "pca_mean" not in arrays:
            return None
        p = cls(*(np.asarray(arrays[k], np.float64) for k in ("pca_mean", "pca_components", "pca_scale")))
        k = p.components.shape[0] if p.components.ndim == 2 else -1
        if p.components.shape != (k, input_dim) or p.mean.shape != (input_dim,) or p.scale.shape != (k,) \
                or not np.all(p.scale > 0):
            raise ValueError("PCA arrays are inconsistent")
        return p


def power_l2(v: np.ndarray, alpha: float = 1.0) -> np.ndarray:
    """Signed power normalisation sign(v)|v|^alpha (alpha = 1: none), then L2 per row. (B, D) -> float32."""
    if alpha != 1.0:
        v = np.sign(v) * np.abs(v) ** alpha
    return (v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12)).astype(np.float32)


def unit_rows(x: np.ndarray) -> np.ndarray:
    """Rows (n, D) -> unit rows float64 (an all-zero row stays zero)."""
    x = np.asarray(x, np.float64)
    norm = np.linalg.norm(x, axis=1, keepdims=True)
    return np.divide(x, norm, out=np.zeros_like(x), where=norm > 0)


def weights_of(x: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    """(B, N) float64 weights: 1 for real descriptors, 0 for padding."""
    return np.ones(x.shape[:2]) if mask is None else np.asarray(mask, np.float64)


class Encoder:
    """Base of every encoder. Subclasses set ``name`` and implement ``transform``, ``dim``, ``to_arrays``,
    ``params``, ``from_arrays`` and (when ``needs_fit``) ``fit``."""

    name: ClassVar[str]
    summary: ClassVar[str]
    needs_fit: ClassVar[bool] = True
    input_dim: int
    pca: Pca | None

    @property
    def dim(self) -> int:
        """D, the length of an encoding."""
        raise NotImplementedError

    @property
    def n_components(self) -> int:
        """Codebook size (GMM components, words, centres); 0 for none."""
        return 0

    def groups(self) -> np.ndarray | None:
        """The codebook entry each encoding dimension belongs to (D,) int64, or None where the dimensions form
        no such groups: ``adapt`` learns one gain a group."""
        return None

    def params(self) -> dict:
        """JSON-serialisable parameters (with ``to_arrays`` they rebuild the encoder)."""
        raise NotImplementedError

    @classmethod
    def fit(cls, x: np.ndarray, s: FitSettings, input_dim: int, local: np.ndarray | None = None,
            mask: np.ndarray | None = None, n_local: int | None = None) -> "Encoder":
        """Fit on descriptors ``x`` (n, input_dim) sampled from the references; ``local`` (R, N, K) and
        ``mask`` (R, N) are every reference's descriptors (bow's tf-idf counts them), ``n_local`` the front
        end's fixed N (None when it varies). Encoders that fit nothing use only ``input_dim``/``n_local``."""
        raise NotImplementedError

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], params: dict, input_dim: int) -> "Encoder":
        """Rebuild a fitted encoder from ``to_arrays()`` and ``params()`` (KeyError/ValueError if inconsistent)."""
        raise NotImplementedError

    def to_arrays(self) -> dict[str, np.ndarray]:
        raise NotImplementedError

    def same_as(self, other: "Encoder") -> bool:
        """True if ``other`` encodes exactly as this one: the same kind, parameters and fitted arrays."""
        if other is self:
            return True
        if type(other) is not type(self) or other.params() != self.params() or other.input_dim != self.input_dim:
            return False
        mine, theirs = self.to_arrays(), other.to_arrays()
        return mine.keys() == theirs.keys() and all(np.array_equal(mine[k], theirs[k]) for k in mine)

    def with_alpha(self, alpha: float) -> "Encoder":
        """The same codebook with another power-normalisation exponent (encoders without one: unchanged)."""
        return self

    def check(self, x: np.ndarray) -> None:
        """Raise VprError unless ``x`` is (B, N, input_dim)."""
        if x.ndim != 3 or x.shape[-1] != self.input_dim:
            raise VprError(f"local descriptors have shape {x.shape[1:]} but the {self.name} encoder expects "
                           f"{self.input_dim}-dim descriptors (a map and its queries must use one front end)")

    def project(self, x: np.ndarray) -> np.ndarray:
        """Raw descriptors (..., input_dim) -> codebook space, float64."""
        y = self.pca.project(x) if self.pca is not None else x
        return np.asarray(y, np.float64)

    def transform(self, x: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
        """(B, N, K) descriptors (mask (B, N) or None) -> (B, D) float32 unit-norm encodings."""
        raise NotImplementedError

    def transform_chunked(self, x: np.ndarray, mask: np.ndarray | None = None, chunk: int = 32) -> np.ndarray:
        """``transform`` over ``chunk`` images at a time (bounded scratch memory for a memmap of references)."""
        return np.concatenate([self.transform(np.asarray(x[i:i + chunk]),
                                              None if mask is None else np.asarray(mask[i:i + chunk]))
                               for i in range(0, len(x), chunk)])

    def save(self, path: str | os.PathLike[str], extra_meta: dict | None = None) -> None:
        """Write a standalone codebook file (atomic): arrays + JSON (``build-map --save-codebook``)."""
        meta = {"kind": "codebook", "schema": CODEBOOK_SCHEMA, "input_dim": self.input_dim,
                "encoding": {"name": self.name, "params": self.params()}}
        write_npz(path, self.to_arrays(), meta | (extra_meta or {}))
