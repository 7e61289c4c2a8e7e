"""Fit the codebook (optional whitened PCA + diagonal GMM) on reference descriptors with scikit-learn.

scikit-learn's PCA and GaussianMixture (k-means initialisation, EM with covariance regularisation) are
well-tested; the fitted parameters are copied into plain arrays (vpr_edge.codebook) so that nothing is
pickled and the runtime needs NumPy only.
"""
from __future__ import annotations

import warnings

import numpy as np

from vpr_edge.codebook import Codebook, Gmm, Pca
from vpr_edge.errors import VprError


def fit_codebook(descriptors: np.ndarray, n_components: int = 128, pca_dim: int | None = None,
                 whiten: bool = True, max_descriptors: int = 30_000, seed: int = 0,
                 max_iter: int = 30) -> Codebook:
    """Fit PCA (if ``pca_dim``) and a diagonal GMM on local descriptors (..., D), sub-sampled at random to at
    most ``max_descriptors`` rows. Raises VprError if there are too few descriptors for the model asked for.
    """
    try:
        from sklearn.decomposition import PCA
        from sklearn.mixture import GaussianMixture
    except ImportError:
        raise VprError("fitting a codebook needs scikit-learn: pip install 'vpr-edge[fit]' "
                       "(or pass an existing --codebook)") from None
    x = np.asarray(descriptors, np.float64).reshape(-1, descriptors.shape[-1])
    dim = x.shape[1]
    rng = np.random.default_rng(seed)
    if len(x) > max_descriptors:
        x = x[rng.choice(len(x), max_descriptors, replace=False)]
    if len(x) < 2 * n_components:
        raise VprError(f"only {len(x)} local descriptors: too few to fit {n_components} GMM components "
                       f"(use fewer components or more reference images)")
    pca = None
    if pca_dim is not None:
        if not 0 < pca_dim <= min(dim, len(x)):
            raise VprError(f"PCA dimension {pca_dim} must be between 1 and {min(dim, len(x))}")
        model = PCA(n_components=pca_dim, whiten=whiten, random_state=seed).fit(x)
        scale = np.sqrt(model.explained_variance_) if whiten else np.ones(pca_dim)
        pca = Pca(model.mean_.astype(np.float64), model.components_.astype(np.float64),
                  np.maximum(scale, 1e-12).astype(np.float64))
        x = pca.project(x).astype(np.float64)
    from sklearn.exceptions import ConvergenceWarning

    with warnings.catch_warnings():  # stopping EM early is the chosen trade (README); not worth a warning
        warnings.simplefilter("ignore", ConvergenceWarning)
        gm = GaussianMixture(n_components=n_components, covariance_type="diag",
                             reg_covar=1e-6 * float(x.var()) + 1e-9, max_iter=max_iter, random_state=seed,
                             init_params="k-means++").fit(x)
    gmm = Gmm(gm.weights_.astype(np.float64), gm.means_.astype(np.float64), gm.covariances_.astype(np.float64))
    return Codebook(gmm, pca, dim)
