"""Fitting codebooks on reference descriptors with scikit-learn (build time only; imported lazily).

scikit-learn's PCA, GaussianMixture (k-means++ initialisation, EM with covariance regularisation) and
MiniBatchKMeans are well-tested; the fitted parameters are copied into plain arrays so that nothing is
pickled and encoding needs NumPy alone.
"""
from __future__ import annotations

import warnings

import numpy as np

from vpr_edge.encoders.base import FitSettings, Pca
from vpr_edge.errors import InputError, VprError, warn


def require_sklearn() -> None:
    """Raise VprError naming the missing extra unless scikit-learn is installed; then import it in the
    background (1.5-2 s here), so that it is ready when the references have been described."""
    import importlib.util
    import threading

    try:
        found = importlib.util.find_spec("sklearn") is not None
    except (ImportError, ValueError):
        found = False
    if not found:
        raise InputError("fitting a codebook needs scikit-learn (sklearn is missing): pip install 'vpr-edge[fit]', "
                         "or pass {opt.codebook} FILE")
    threading.Thread(target=_import_sklearn, daemon=True, name="import-sklearn").start()


def _import_sklearn() -> None:
    try:
        import sklearn.cluster  # noqa: F401
        import sklearn.mixture  # noqa: F401
    except Exception:  # a broken install fails again, with its message, where the fit imports it
        pass


def sample_descriptors(local: np.ndarray, mask: np.ndarray | None, limit: int, seed: int) -> np.ndarray:
    """At most ``limit`` real descriptors drawn at random (no replacement) from ``local`` (R, N, K), a
    memmap or an array -> (n, K) float64, rows in storage order."""
    r, n, k = local.shape
    real = np.flatnonzero(np.ones(r * n, bool) if mask is None else np.asarray(mask).reshape(-1))
    rng = np.random.default_rng(seed)
    rows = np.sort(rng.choice(real, min(limit, len(real)), replace=False))
    return np.asarray(local.reshape(r * n, k)[rows], np.float64)


def fit_pca(x: np.ndarray, s: FitSettings) -> tuple[Pca | None, np.ndarray]:
    """PCA of ``x`` (n, D) to ``s.pca_dim`` dims (whitened if ``s.whiten``) and ``x`` projected; (None, x)
    when ``s.pca_dim`` is None."""
    if s.pca_dim is None:
        return None, x
    from sklearn.decomposition import PCA

    if not 0 < s.pca_dim <= min(x.shape):
        raise VprError(f"PCA dimension {s.pca_dim} must be between 1 and {min(x.shape)}")
    model = PCA(n_components=s.pca_dim, whiten=s.whiten, random_state=s.seed).fit(x)
    scale = np.sqrt(model.explained_variance_) if s.whiten else np.ones(s.pca_dim)
    pca = Pca(model.mean_.astype(np.float64), model.components_.astype(np.float64),
              np.maximum(scale, 1e-12).astype(np.float64))
    return pca, pca.project(x).astype(np.float64)


def _enough(x: np.ndarray, k: int, what: str) -> None:
    if len(x) < 2 * k:
        raise VprError(f"only {len(x)} local descriptors: too few to fit {k} {what} "
                       f"(use fewer components or more reference images)")


INIT_SAMPLE = 5_000   # descriptors the k-means++ seeds are drawn from (on all 30,000 it took 1.9 of 7 s)


def fit_gmm(x: np.ndarray, s: FitSettings) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Diagonal GMM with ``s.n_components`` components on ``x`` (n, K) -> (weights, means, variances) float64.

    scikit-learn's EM, started as its own ``k-means++`` start does (means at k-means++ seeds, equal weights,
    variances at the regularisation floor, so the first E-step assigns each descriptor to its nearest seed)
    but with the seeds drawn from ``INIT_SAMPLE`` descriptors; EM runs in float32 (every array given to it is
    float32, or NumPy promotes the whole EM to float64), faster than float64 (docs/decisions.md, "Tried and not
    taken")."""
    from sklearn.cluster import kmeans_plusplus
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.mixture import GaussianMixture

    _enough(x, s.n_components, "GMM components")
    x = np.asarray(x, np.float32)
    m, k = s.n_components, x.shape[1]
    reg = 1e-6 * float(x.var(dtype=np.float64)) + 1e-9
    rng = np.random.default_rng(s.seed)
    pool = x if len(x) <= INIT_SAMPLE else x[np.sort(rng.choice(len(x), INIT_SAMPLE, replace=False))]
    seeds, _ = kmeans_plusplus(pool, m, random_state=s.seed)
    def em(data: np.ndarray, reg: float):
        dt = data.dtype
        with warnings.catch_warnings():  # stopping EM early is the chosen trade (docs/decisions.md): no warning
            warnings.simplefilter("ignore", ConvergenceWarning)
            return GaussianMixture(n_components=m, covariance_type="diag", reg_covar=reg, max_iter=s.iterations,
                                   random_state=s.seed, init_params="random_from_data",
                                   weights_init=np.full(m, 1.0 / m, dt), means_init=seeds.astype(dt),
                                   precisions_init=np.full((m, k), 1.0 / reg, dt)).fit(data)

    try:
        gm = em(x, reg)
    except ValueError:
        # a component collapsed onto identical descriptors (flat image regions: HOG of a uniform sky), whose
        # float32 variance rounds to <= 0: EM again in float64, then with a floor 1,000 times higher
        try:
            gm = em(x.astype(np.float64), reg)
        except ValueError:
            warn("codebook: descriptors too alike for the default variance floor; refitted with 1e-3 of their "
                 "variance as the floor")
            gm = em(x.astype(np.float64), 1e3 * reg)
    return (gm.weights_.astype(np.float64), gm.means_.astype(np.float64), gm.covariances_.astype(np.float64))


def fit_kmeans(x: np.ndarray, s: FitSettings) -> np.ndarray:
    """``s.n_components`` k-means centres of ``x`` (n, K) (MiniBatchKMeans, k-means++) -> (k, K) float64."""
    from sklearn.cluster import MiniBatchKMeans

    _enough(x, s.n_components, "k-means centres")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")   # convergence and duplicate-point notices
        km = MiniBatchKMeans(n_clusters=s.n_components, random_state=s.seed, n_init=3, max_iter=max(s.iterations, 10),
                             batch_size=2048).fit(x)
    return km.cluster_centers_.astype(np.float64)
