"""Fisher vectors on a diagonal GMM: plain (``fv``, Perronnin & Dance 2007) and improved (``ifv``,
Perronnin et al. 2010: signed power normalisation, L2), the thesis's encoding."""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from vpr_edge.encoders.base import Encoder, FitSettings, Pca, power_l2, weights_of

_LOG_2PI = float(np.log(2.0 * np.pi))


@dataclass(frozen=True)
class Gmm:
    """Diagonal GMM: weights (M,), means (M, K), variances (M, K); all float64, variances > 0."""

    weights: np.ndarray
    means: np.ndarray
    variances: np.ndarray

    @property
    def n_components(self) -> int:
        return int(self.weights.shape[0])

    @property
    def dim(self) -> int:
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


def fisher_gradients(y: np.ndarray, w: np.ndarray, gmm: Gmm) -> np.ndarray:
    """Fisher-information-normalised gradients of the mean log-likelihood of descriptor sets.

    y (B, N, K) float64 in GMM space, w (B, N) descriptor weights (0 = padding). Returns (B, 2*M*K): the
    gradients with respect to the means (first M*K) and standard deviations (last M*K), component-major,
    scaled by 1/sqrt(w_k) and 1/sqrt(2 w_k) and divided by the number of descriptors."""
    gamma = np.exp(gmm.log_responsibilities(y)) * w[..., None]               # (B, N, M)
    n = np.maximum(w.sum(axis=1), 1.0)                                        # (B,)
    s0 = gamma.sum(axis=1)                                                    # (B, M)
    gamma_t = gamma.transpose(0, 2, 1)                                        # (B, M, N)
    s1 = gamma_t @ y                                                          # (B, M, K)
    s2 = gamma_t @ (y * y)                                                    # (B, M, K)
    mu, var = gmm.means, gmm.variances
    sigma = np.sqrt(var)
    g_mu = (s1 - s0[..., None] * mu) / (sigma * np.sqrt(gmm.weights)[:, None]) / n[:, None, None]
    g_sigma = (s2 - 2.0 * s1 * mu + s0[..., None] * (mu * mu - var)) / (
        var * np.sqrt(2.0 * gmm.weights)[:, None]) / n[:, None, None]
    return np.concatenate([g_mu.reshape(len(y), -1), g_sigma.reshape(len(y), -1)], axis=1)


@dataclass(frozen=True)
class FisherVector(Encoder):
    """Plain Fisher vector: the gradients as they are (no power normalisation). Maps compare encodings by
    cosine, so each is stored L2-normalised; that is the only step it shares with ``ifv``."""

    name: ClassVar[str] = "fv"
    summary: ClassVar[str] = "Fisher vector on a diagonal GMM (mean and variance gradients, no power normalisation)"
    gmm: Gmm
    pca: Pca | None
    input_dim: int
    alpha: float = 1.0
    powers: ClassVar[bool] = False   # takes the fit's power normalisation (FitSettings.alpha)

    @property
    def dim(self) -> int:
        return 2 * self.gmm.n_components * self.gmm.dim

    @property
    def n_components(self) -> int:
        return self.gmm.n_components

    def groups(self) -> np.ndarray:
        """Each dimension's GMM component: the mean gradients (K, d) then the variance gradients (K, d)."""
        return np.tile(np.repeat(np.arange(self.gmm.n_components, dtype=np.int64), self.gmm.dim), 2)

    def params(self) -> dict:
        return {"alpha": self.alpha}

    def to_arrays(self) -> dict[str, np.ndarray]:
        out = {"gmm_weights": self.gmm.weights, "gmm_means": self.gmm.means, "gmm_variances": self.gmm.variances}
        return out | (self.pca.to_arrays() if self.pca is not None else {})

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], params: dict, input_dim: int) -> "FisherVector":
        gmm = Gmm(*(np.asarray(arrays[k], np.float64) for k in ("gmm_weights", "gmm_means", "gmm_variances")))
        pca = Pca.from_arrays(arrays, input_dim)
        m, k = gmm.means.shape if gmm.means.ndim == 2 else (-1, -1)
        ok = gmm.weights.shape == (m,) and gmm.variances.shape == (m, k) and bool(np.all(gmm.variances > 0))
        ok = ok and bool(np.all(gmm.weights > 0)) and k == (pca.components.shape[0] if pca else input_dim)
        if not ok:
            raise ValueError("GMM arrays are inconsistent (shapes or non-positive variances)")
        return cls(gmm, pca, input_dim, float(params.get("alpha", cls.alpha)))

    @classmethod
    def fit(cls, x: np.ndarray, s: FitSettings, input_dim: int, local: np.ndarray | None = None,
            mask: np.ndarray | None = None, n_local: int | None = None) -> "FisherVector":
        """Fit on sampled descriptors ``x`` (n, input_dim)."""
        from vpr_edge.encoders.fit import fit_gmm, fit_pca

        pca, y = fit_pca(x, s)
        return cls(Gmm(*fit_gmm(y, s)), pca, input_dim, s.alpha if cls.powers else cls.alpha)

    def transform(self, x: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
        self.check(x)
        return power_l2(fisher_gradients(self.project(x), weights_of(x, mask), self.gmm), self.alpha)


@dataclass(frozen=True)
class ImprovedFisherVector(FisherVector):
    """Improved Fisher vector: the Fisher vector, signed power normalisation |z|^alpha, L2."""

    name: ClassVar[str] = "ifv"
    summary: ClassVar[str] = "Improved Fisher vector: fv + signed power normalisation + L2 (the thesis's)"
    alpha: float = 0.5
    powers: ClassVar[bool] = True

    def with_alpha(self, alpha: float) -> "ImprovedFisherVector":
        return replace(self, alpha=alpha)
