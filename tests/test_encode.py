"""IFV encoder and codebook maths against direct per-component, per-descriptor formulas."""
from __future__ import annotations

import numpy as np
import pytest

from vpr_edge.codebook import Codebook, Gmm, Pca
from vpr_edge.encode import fisher_vector


def random_codebook(rng: np.random.Generator, m: int = 5, k: int = 4, d: int | None = None) -> Codebook:
    w = rng.random(m) + 0.2
    gmm = Gmm(w / w.sum(), rng.normal(size=(m, k)), rng.random((m, k)) + 0.3)
    if d is None:
        return Codebook(gmm, None, k)
    pca = Pca(rng.normal(size=d), np.linalg.qr(rng.normal(size=(d, k)))[0].T, rng.random(k) + 0.5)
    return Codebook(gmm, pca, d)


def naive_posteriors(x: np.ndarray, gmm: Gmm) -> np.ndarray:
    dens = np.zeros((len(x), gmm.n_components))
    for n in range(len(x)):
        for c in range(gmm.n_components):
            var = gmm.variances[c]
            dens[n, c] = gmm.weights[c] * np.prod(np.exp(-0.5 * (x[n] - gmm.means[c]) ** 2 / var)
                                                  / np.sqrt(2 * np.pi * var))
    return dens / dens.sum(axis=1, keepdims=True)


def naive_fisher(x: np.ndarray, cb: Codebook, alpha: float) -> np.ndarray:
    y = cb.project(x)
    g = cb.gmm
    post = naive_posteriors(y, g)
    n = len(y)
    mu_part, sig_part = [], []
    for c in range(g.n_components):
        sd = np.sqrt(g.variances[c])
        gm = np.zeros(g.dim)
        gs = np.zeros(g.dim)
        for i in range(n):
            z = (y[i] - g.means[c]) / sd
            gm += post[i, c] * z
            gs += post[i, c] * (z * z - 1)
        mu_part.append(gm / (n * np.sqrt(g.weights[c])))
        sig_part.append(gs / (n * np.sqrt(2 * g.weights[c])))
    fv = np.concatenate(mu_part + sig_part)
    fv = np.sign(fv) * np.abs(fv) ** alpha
    return fv / np.linalg.norm(fv)


def test_posteriors_match_direct_densities() -> None:
    rng = np.random.default_rng(1)
    cb = random_codebook(rng)
    x = rng.normal(size=(30, 4))
    got = np.exp(cb.gmm.log_responsibilities(x))
    np.testing.assert_allclose(got, naive_posteriors(x, cb.gmm), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(got.sum(axis=1), 1.0)


def test_posteriors_stable_far_from_all_components() -> None:
    rng = np.random.default_rng(2)
    cb = random_codebook(rng)
    post = np.exp(cb.gmm.log_responsibilities(np.full((3, 4), 1e3)))
    assert np.all(np.isfinite(post))
    np.testing.assert_allclose(post.sum(axis=1), 1.0)


@pytest.mark.parametrize("alpha", [0.5, 1.0])
@pytest.mark.parametrize("pca_dim", [None, 7])
def test_fisher_vector_matches_naive(alpha: float, pca_dim: int | None) -> None:
    rng = np.random.default_rng(3)
    cb = random_codebook(rng, m=5, k=4, d=pca_dim)
    x = rng.normal(size=(3, 20, cb.input_dim))
    got = fisher_vector(x, cb, alpha)
    assert got.shape == (3, 2 * 5 * 4) and got.dtype == np.float32
    for b in range(3):
        np.testing.assert_allclose(got[b], naive_fisher(x[b], cb, alpha), rtol=2e-5, atol=2e-6)
    np.testing.assert_allclose(np.linalg.norm(got, axis=1), 1.0, rtol=1e-5)
    np.testing.assert_array_equal(fisher_vector(x[1], cb, alpha), got[1])


def test_identical_sets_encode_identically_and_differ_from_others() -> None:
    rng = np.random.default_rng(4)
    cb = random_codebook(rng)
    a, b = rng.normal(size=(50, 4)), rng.normal(loc=1.0, size=(50, 4))
    fa, fa_shuffled, fb = fisher_vector(np.stack([a, a[::-1], b]), cb)
    np.testing.assert_allclose(fa, fa_shuffled, atol=1e-6)  # orderless: a set, not a sequence
    assert float(fa @ fb) < 0.99
