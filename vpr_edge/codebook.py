"""The codebook: optional PCA (with whitening) and a diagonal-covariance GMM over local descriptors.

Fitted offline by ``vpr_edge_export.codebook_fit`` (scikit-learn); used here with NumPy only.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from vpr_edge.errors import VprError
from vpr_edge.store import read_npz, write_npz

CODEBOOK_SCHEMA = 1
_LOG_2PI = float(np.log(2.0 * np.pi))


@dataclass(frozen=True)
class Pca:
    """Projection x -> ((x - mean) @ components.T) / scale. mean (D,), components (K, D), scale (K,)."""

    mean: np.ndarray
    components: np.ndarray
    scale: np.ndarray

    def project(self, x: np.ndarray) -> np.ndarray:
        """(..., D) -> (..., K) float32."""
        return ((x - self.mean) @ self.components.T / self.scale).astype(np.float32, copy=False)


@dataclass(frozen=True)
class Gmm:
    """Diagonal GMM: weights (M,), means (M, K), variances (M, K); all float64, variances > 0."""

    weights: np.ndarray
    means: np.ndarray
    variances: np.ndarray

    @property
    def n_components(self) -> int:
        """M."""
        return int(self.weights.shape[0])

    @property
    def dim(self) -> int:
        """K."""
        return int(self.means.shape[1])

    def log_responsibilities(self, x: np.ndarray) -> np.ndarray:
        """Descriptors (..., N, K) -> log posteriors log p(k | x_n), (..., N, M), by log-sum-exp."""
        inv = 1.0 / self.variances                                           # (M, K)
        quad = (x * x) @ inv.T - 2.0 * (x @ (self.means * inv).T)            # (..., N, M)
        const = (np.log(self.weights) - 0.5 * (np.sum(self.means ** 2 * inv, axis=1)
                                               + np.sum(np.log(self.variances), axis=1) + self.dim * _LOG_2PI))
        logp = const - 0.5 * quad
        top = logp.max(axis=-1, keepdims=True)
        return logp - (top + np.log(np.exp(logp - top).sum(axis=-1, keepdims=True)))


@dataclass(frozen=True)
class Codebook:
    """PCA (or None: descriptors used as they are) followed by a GMM in the projected space."""

    gmm: Gmm
    pca: Pca | None = None
    input_dim: int = 0

    def project(self, x: np.ndarray) -> np.ndarray:
        """Raw descriptors (..., D) -> GMM space (..., K) float64."""
        if x.shape[-1] != self.input_dim:
            raise VprError(f"descriptors have {x.shape[-1]} dims but the codebook expects {self.input_dim}")
        y = self.pca.project(x) if self.pca is not None else x
        return y.astype(np.float64, copy=False)

    def to_arrays(self, prefix: str = "") -> dict[str, np.ndarray]:
        """Arrays for storage, names prefixed with ``prefix``."""
        out = {"gmm_weights": self.gmm.weights, "gmm_means": self.gmm.means, "gmm_variances": self.gmm.variances}
        if self.pca is not None:
            out |= {"pca_mean": self.pca.mean, "pca_components": self.pca.components, "pca_scale": self.pca.scale}
        return {prefix + k: v for k, v in out.items()}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], input_dim: int, prefix: str = "",
                    source: str = "codebook") -> "Codebook":
        """Inverse of :meth:`to_arrays`; checks shapes and positivity, naming ``source`` on error."""
        try:
            gmm = Gmm(*(np.asarray(arrays[prefix + k], np.float64)
                        for k in ("gmm_weights", "gmm_means", "gmm_variances")))
            pca = None
            if prefix + "pca_mean" in arrays:
                pca = Pca(*(np.asarray(arrays[prefix + k], np.float64)
                            for k in ("pca_mean", "pca_components", "pca_scale")))
        except KeyError as e:
            raise VprError(f"{source}: codebook array {e} missing") from None
        m, k = gmm.means.shape if gmm.means.ndim == 2 else (-1, -1)
        ok = gmm.weights.shape == (m,) and gmm.variances.shape == (m, k) and np.all(gmm.variances > 0)
        ok = ok and np.all(gmm.weights > 0)
        if pca is not None:
            ok = ok and pca.components.shape == (k, input_dim) and pca.mean.shape == (input_dim,)
            ok = ok and pca.scale.shape == (k,) and np.all(pca.scale > 0)
        elif k != input_dim:
            ok = False
        if not ok:
            raise VprError(f"{source}: codebook arrays are inconsistent (shapes or non-positive variances)")
        return cls(gmm, pca, input_dim)

    def save(self, path: str | os.PathLike[str], extra_meta: dict | None = None) -> None:
        """Write a standalone codebook file (atomic)."""
        meta = {"kind": "codebook", "schema": CODEBOOK_SCHEMA, "input_dim": self.input_dim,
                "n_components": self.gmm.n_components, "pca_dim": self.gmm.dim if self.pca else None}
        write_npz(path, self.to_arrays(), meta | (extra_meta or {}))

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> tuple["Codebook", dict]:
        """Read a standalone codebook file; returns (codebook, metadata)."""
        arrays, meta = read_npz(path, "codebook", CODEBOOK_SCHEMA)
        return cls.from_arrays(arrays, int(meta.get("input_dim", 0)), source=str(path)), meta
