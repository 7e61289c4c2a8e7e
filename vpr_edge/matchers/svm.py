"""The thesis's classifier baseline: one linear SVM per reference place, trained on the references.

Positives for place r are the references within ``tolerance`` frames of r (its neighbours on the route are
real views of the same place from a slightly different pose, which is what augmented views would imitate,
without a second pass over the images); negatives are all the others. Classes are weighted so that the
three or so positives count as much as the negatives. The SVMs are fitted in the span of the references
(X = U S V^T, features X V, weights mapped back by V): exact for a linear SVM, whose weights lie in that
span, and R-dimensional instead of D-dimensional. At run time a frame is scored by one matrix product
(``map.model.Svm``); the ``svm`` matcher takes the place with the highest decision value.
"""
from __future__ import annotations

import warnings

import numpy as np

from vpr_edge.errors import VprError

from vpr_edge.matchers.constants import SVM_C


def fit_svm(encodings: np.ndarray, tolerance: int = 1, c: float = SVM_C,
            seed: int = 0) -> tuple[np.ndarray, np.ndarray, dict]:
    """Train R one-vs-rest linear SVMs on reference encodings (R, D) -> (weights (R, D) float32,
    bias (R,) float32, metadata). Needs scikit-learn (the fit extra)."""
    try:
        from sklearn.multiclass import OneVsRestClassifier
        from sklearn.svm import LinearSVC
    except ImportError:
        raise VprError("training the SVM needs scikit-learn: pip install 'vpr-edge[fit]'") from None
    x = np.asarray(encodings, np.float64)
    r = len(x)
    if r < 3:
        raise VprError(f"an SVM per place needs at least 3 references, got {r}")
    u, s, vt = np.linalg.svd(x, full_matrices=False)                    # x = u s vt
    z = u * s                                                             # (R, r) = x @ vt.T
    idx = np.arange(r)
    labels = (np.abs(idx[:, None] - idx[None, :]) <= tolerance).astype(int)   # (R samples, R classes)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")   # liblinear convergence notices
        ovr = OneVsRestClassifier(LinearSVC(C=c, class_weight="balanced", dual=True, max_iter=2000,
                                            random_state=seed)).fit(z, labels)
    coef = np.stack([e.coef_[0] for e in ovr.estimators_])               # (R, r)
    bias = np.array([e.intercept_[0] for e in ovr.estimators_])
    meta = {"positives": f"references within {tolerance} frame(s) of the place", "C": c,
            "class_weight": "balanced", "tolerance": tolerance}
    return (coef @ vt).astype(np.float32), bias.astype(np.float32), meta
