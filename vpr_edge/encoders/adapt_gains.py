"""One gain a codebook entry, learned from labelled pairs (``encoders.adapt``'s first and last steps).

An IFV or VLAD encoding is made of one block a codebook entry (a GMM component, a centre). Some entries
describe what a place looks like whatever the season; others describe the snow, the sky or the light. One
gain a block, ``w = exp(theta)`` on its squared dimensions, weighs them: the cosine of two encodings becomes

    S_ij = sum_d w_d q_id r_jd / (|q_i|_w |r_j|_w),    |x|_w = sqrt(sum_d w_d x_d^2)

and ``theta`` (one value a group) minimises a contrastive loss over the pairs: each labelled frame's softmax
over every pair's reference (temperature ``tau``) should put its mass on the references within ``tolerance``
places of its own, and each reference's softmax over the frames likewise, plus ``reg`` times the mean of
``theta^2`` (the gains stay near 1 where the pairs say little). A few dozen gains are learned from a few
hundred pairs where a full linear map is not (docs/decisions.md, "`adapt`: chosen on the drive's own places").

The sums over each group's dimensions are taken once (``GroupSums``: G products of N x N), so each step of
the fit costs O(G N^2) whatever the encoding's length. The gradient is exact (tested against finite
differences); L-BFGS (SciPy, the ``fit`` extra) minimises the loss.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

TAU = 0.03              # the softmax temperature over cosines
GAIN_REG = 1.0          # the pull of each log-gain towards 0 (gain 1)
GAIN_CELLS = 30_000_000  # at most this many group-pair products held (G x N x N): fewer pairs where G is large
TOLERANCE = 2           # references within this many places of a frame's own count as its place


@dataclass(frozen=True)
class GroupSums:
    """Each group's share of the pairs' dot products and squared norms: ``products`` (G, N, N) float32,
    sum over the group's dimensions of q_id r_jd; ``q_sq``, ``r_sq`` (N, G), sums of q_id^2 and r_jd^2."""

    products: np.ndarray
    q_sq: np.ndarray
    r_sq: np.ndarray

    @classmethod
    def of(cls, q: np.ndarray, r: np.ndarray, groups: np.ndarray) -> "GroupSums":
        """From frames ``q`` and references ``r`` (N, D) and each dimension's group (D,) in 0..G-1."""
        n_groups = int(groups.max()) + 1
        products = np.empty((n_groups, len(q), len(r)), np.float32)
        q_sq, r_sq = np.empty((len(q), n_groups)), np.empty((len(r), n_groups))
        for g in range(n_groups):
            dims = groups == g
            products[g] = q[:, dims] @ r[:, dims].T
            q_sq[:, g] = (q[:, dims] ** 2).sum(axis=1)
            r_sq[:, g] = (r[:, dims] ** 2).sum(axis=1)
        return cls(products, q_sq, r_sq)


def contrastive_loss(theta: np.ndarray, sums: GroupSums, near: np.ndarray, tau: float = TAU,
                     reg: float = GAIN_REG) -> tuple[float, np.ndarray]:
    """The loss (module docstring) and its gradient in ``theta`` (G,): the pairs' ``sums``, ``near`` (N, N)
    bool: pair j's reference lies within the tolerance of pair i's place (every row holds its own pair)."""
    w = np.exp(theta)
    n = sums.products.shape[1]
    dot = np.tensordot(w, sums.products, axes=1).astype(np.float64)
    a, b = np.sqrt(sums.q_sq @ w), np.sqrt(sums.r_sq @ w)
    s = dot / np.outer(a, b)
    loss, grad_s = 0.0, np.zeros_like(s)
    for m, transposed in ((s, False), (s.T, True)):
        z = m / tau
        z = z - z.max(axis=1, keepdims=True)
        p = np.exp(z)
        p /= p.sum(axis=1, keepdims=True)
        pos = near.T if transposed else near
        hit = (p * pos).sum(axis=1)
        loss -= float(np.log(hit).mean())
        g = (p - p * pos / hit[:, None]) / (n * tau)
        grad_s += g.T if transposed else g
    gs = grad_s * s
    grad_w = (np.tensordot(sums.products, grad_s / np.outer(a, b), axes=([1, 2], [0, 1]))
              - 0.5 * (gs.sum(axis=1) / a ** 2) @ sums.q_sq - 0.5 * (gs.sum(axis=0) / b ** 2) @ sums.r_sq)
    return loss + reg * float(theta @ theta) / len(theta), grad_w * w + 2.0 * reg * theta / len(theta)


def fit_gains(queries: np.ndarray, refs: np.ndarray, places: np.ndarray, groups: np.ndarray, tau: float = TAU,
              reg: float = GAIN_REG, tolerance: int = TOLERANCE, seed: int = 0) -> np.ndarray:
    """Labelled frames' encodings ``queries`` and their references ``refs`` (N, D), each pair's place
    ``places`` (N,), the dimensions' ``groups`` (D,) -> each dimension's gain (D,) float64, sqrt(w) (the
    encodings are scaled by it, so cosines weigh w). Each set is centred first (the cosine the
    standardised matching reads); where G x N x N passes ``GAIN_CELLS``, a seeded sample of the pairs fits."""
    from scipy.optimize import minimize

    q = np.asarray(queries, np.float64)
    r = np.asarray(refs, np.float64)
    places = np.asarray(places, np.int64)
    n_groups = int(groups.max()) + 1
    most = max(2, int(math.sqrt(GAIN_CELLS / n_groups)))
    if len(q) > most:
        keep = np.sort(np.random.default_rng(seed).choice(len(q), most, replace=False))
        q, r, places = q[keep], r[keep], places[keep]
    q, r = q - q.mean(axis=0), r - r.mean(axis=0)
    near = np.abs(places[:, None] - places[None, :]) <= tolerance
    sums = GroupSums.of(q, r, groups)
    res = minimize(contrastive_loss, np.zeros(n_groups), args=(sums, near, tau, reg), jac=True,
                   method="L-BFGS-B", options={"maxiter": 200})
    return np.sqrt(np.exp(res.x))[groups]
