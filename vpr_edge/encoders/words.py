"""Codebooks of k-means centres: bag of words (``bow``, Sivic & Zisserman 2003) and VLAD (Jegou et al. 2010,
with intra-normalisation, Arandjelovic & Zisserman 2013)."""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from vpr_edge.encoders.base import Encoder, FitSettings, Pca, power_l2, weights_of


def nearest_centre(y: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Index of the nearest centre (squared Euclidean) of each descriptor: y (..., K), centres (C, K) -> (...,)."""
    d = (centres * centres).sum(axis=1) - 2.0 * (y @ centres.T)                 # ||y||^2 is the same per row
    return d.argmin(axis=-1)


def _one_hot(y: np.ndarray, w: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """(B, N, C) assignment weights: w where a descriptor's nearest centre is c, else 0."""
    idx = nearest_centre(y, centres)
    return (idx[..., None] == np.arange(len(centres))) * w[..., None]


@dataclass(frozen=True)
class _Centres(Encoder):
    centres: np.ndarray            # (C, K) float64, in PCA space if pca
    pca: Pca | None
    input_dim: int

    @property
    def n_components(self) -> int:
        return int(self.centres.shape[0])

    def _arrays(self) -> dict[str, np.ndarray]:
        return {"centres": self.centres} | (self.pca.to_arrays() if self.pca is not None else {})

    @staticmethod
    def _load(arrays: dict[str, np.ndarray], input_dim: int) -> tuple[np.ndarray, Pca | None]:
        centres = np.asarray(arrays["centres"], np.float64)
        pca = Pca.from_arrays(arrays, input_dim)
        if centres.ndim != 2 or centres.shape[1] != (pca.components.shape[0] if pca else input_dim):
            raise ValueError("centre arrays are inconsistent")
        return centres, pca


@dataclass(frozen=True)
class BagOfWords(_Centres):
    """Hard-assignment word histogram / number of descriptors (tf), times idf when fitted with tf-idf, L2.
    D = C words."""

    name: ClassVar[str] = "bow"
    summary: ClassVar[str] = "bag of visual words: k-means vocabulary, hard assignment, optional tf-idf, L2"
    idf: np.ndarray | None = None  # (C,) float64

    @property
    def dim(self) -> int:
        return self.n_components

    def params(self) -> dict:
        return {"tfidf": self.idf is not None}

    def to_arrays(self) -> dict[str, np.ndarray]:
        return self._arrays() | ({"idf": self.idf} if self.idf is not None else {})

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], params: dict, input_dim: int) -> "BagOfWords":
        centres, pca = cls._load(arrays, input_dim)
        idf = np.asarray(arrays["idf"], np.float64) if params.get("tfidf") else None
        if idf is not None and idf.shape != (len(centres),):
            raise ValueError("idf array is inconsistent")
        return cls(centres, pca, input_dim, idf)

    def histogram(self, x: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
        """Term frequencies (B, C): the share of an image's descriptors assigned to each word."""
        w = weights_of(x, mask)
        counts = _one_hot(self.project(x), w, self.centres).sum(axis=1)
        return counts / np.maximum(w.sum(axis=1, keepdims=True), 1.0)

    @classmethod
    def fit(cls, x: np.ndarray, s: FitSettings, input_dim: int, local: np.ndarray | None = None,
            mask: np.ndarray | None = None, n_local: int | None = None) -> "BagOfWords":
        """Vocabulary from sampled descriptors ``x``; with ``s.tfidf`` the idf log((1+R)/(1+df)) from every
        reference image in ``local`` (R, N, K) (df: references holding the word)."""
        from vpr_edge.encoders.fit import fit_kmeans, fit_pca

        pca, y = fit_pca(x, s)
        bow = cls(fit_kmeans(y, s), pca, input_dim)
        if not s.tfidf or local is None:
            return bow
        df = np.zeros(bow.n_components)
        for i in range(0, len(local), 64):
            tf = bow.histogram(np.asarray(local[i:i + 64]), None if mask is None else np.asarray(mask[i:i + 64]))
            df += (tf > 0).sum(axis=0)
        return replace(bow, idf=np.log((1.0 + len(local)) / (1.0 + df)))

    def transform(self, x: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
        self.check(x)
        tf = self.histogram(x, mask)
        return power_l2(tf * self.idf if self.idf is not None else tf)


@dataclass(frozen=True)
class Vlad(_Centres):
    """Sums of residuals to the nearest centre, each centre's sum L2-normalised (intra-normalisation),
    then signed power |z|^alpha and L2. D = C * K."""

    name: ClassVar[str] = "vlad"
    summary: ClassVar[str] = "VLAD: residuals to k-means centres, intra-normalised, signed power + L2"
    alpha: float = 0.5

    @property
    def dim(self) -> int:
        return int(self.centres.size)

    def groups(self) -> np.ndarray:
        """Each dimension's centre (C, K row-major)."""
        return np.repeat(np.arange(len(self.centres), dtype=np.int64), self.centres.shape[1])

    def params(self) -> dict:
        return {"alpha": self.alpha}

    def to_arrays(self) -> dict[str, np.ndarray]:
        return self._arrays()

    def with_alpha(self, alpha: float) -> "Vlad":
        return replace(self, alpha=alpha)

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], params: dict, input_dim: int) -> "Vlad":
        centres, pca = cls._load(arrays, input_dim)
        return cls(centres, pca, input_dim, float(params.get("alpha", 0.5)))

    @classmethod
    def fit(cls, x: np.ndarray, s: FitSettings, input_dim: int, local: np.ndarray | None = None,
            mask: np.ndarray | None = None, n_local: int | None = None) -> "Vlad":
        from vpr_edge.encoders.fit import fit_kmeans, fit_pca

        pca, y = fit_pca(x, s)
        return cls(fit_kmeans(y, s), pca, input_dim, s.alpha)

    def transform(self, x: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
        self.check(x)
        y = self.project(x)
        a = _one_hot(y, weights_of(x, mask), self.centres)                     # (B, N, C)
        v = a.transpose(0, 2, 1) @ y - a.sum(axis=1)[..., None] * self.centres  # (B, C, K)
        v = v / np.maximum(np.linalg.norm(v, axis=2, keepdims=True), 1e-12)
        return power_l2(v.reshape(len(x), -1), self.alpha)
