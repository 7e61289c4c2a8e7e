"""Improved Fisher Vector encoding of local descriptor sets (NumPy, vectorised over images and features)."""
from __future__ import annotations

import numpy as np

from vpr_edge.codebook import Codebook


def fisher_vector(x: np.ndarray, codebook: Codebook, alpha: float = 0.5) -> np.ndarray:
    """Improved Fisher Vectors of descriptor sets.

    x: (B, N, D) or (N, D) raw local descriptors. Returns float32 (B, 2*M*K) or (2*M*K,): the gradients
    with respect to the GMM means (first M*K) and standard deviations (last M*K), component-major,
    each normalised by the Fisher information (1/sqrt(w) and 1/sqrt(2w)) and by N; then signed power
    normalisation |z|^alpha (alpha=1 disables it) and L2 normalisation. K is the GMM dimension (after PCA).
    """
    single = x.ndim == 2
    xb = codebook.project(x[None] if single else x)                           # (B, N, K)
    gmm = codebook.gmm
    n = xb.shape[1]
    gamma = np.exp(gmm.log_responsibilities(xb))                              # (B, N, M)
    s0 = gamma.sum(axis=1)                                                    # (B, M)
    gamma_t = gamma.transpose(0, 2, 1)                                        # (B, M, N)
    s1 = gamma_t @ xb                                                         # (B, M, K)
    s2 = gamma_t @ (xb * xb)                                                  # (B, M, K)
    mu, var = gmm.means, gmm.variances
    sigma = np.sqrt(var)
    g_mu = (s1 - s0[..., None] * mu) / (sigma * (n * np.sqrt(gmm.weights))[:, None])
    g_sigma = (s2 - 2.0 * s1 * mu + s0[..., None] * (mu * mu - var)) / (
        var * (n * np.sqrt(2.0 * gmm.weights))[:, None])
    fv = np.concatenate([g_mu.reshape(len(xb), -1), g_sigma.reshape(len(xb), -1)], axis=1)
    if alpha != 1.0:
        fv = np.sign(fv) * np.abs(fv) ** alpha
    norms = np.linalg.norm(fv, axis=1, keepdims=True)
    fv = (fv / np.maximum(norms, 1e-12)).astype(np.float32)
    return fv[0] if single else fv
