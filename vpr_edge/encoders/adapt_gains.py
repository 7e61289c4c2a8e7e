"""One gain a codebook entry, learned from labelled pairs (``encoders.adapt``'s first and last steps).

An IFV or VLAD encoding is made of one block a codebook entry (a GMM component, a centre). Some entries
describe what a place looks like whatever the season; others describe the snow, the sky or the light. One
gain a block, ``w = exp(theta)`` on its squared dimensions, weighs them: the cosine of two encodings becomes

    S_ij = sum_d w_d q_id r_jd / (|q_i|_w |r_j|_w),    |x|_w = sqrt(sum_d w_d x_d^2)

and ``theta`` (one value a group) minimises a contrastive loss over the pairs: each labelled frame's softmax
over every pair's reference (temperature ``tau``) should put its mass on the references within ``tolerance``
places of its own, and each reference's softmax over the frames likewise, plus ``reg`` times the mean of
``theta^2`` (the gains stay near 1 where the pairs say little). A few dozen gains are learned from a few
hundred pairs where a full linear map is not (docs/usage.md, "Fitting vpr-edge to your route").

The gradient is exact (tested against finite differences); L-BFGS (SciPy, the ``fit`` extra) minimises it.
"""
from __future__ import annotations

import numpy as np

TAU = 0.03          # the softmax temperature over cosines
GAIN_REG = 1.0      # the pull of each log-gain towards 0 (gain 1)
GAIN_PAIRS = 2000   # at most this many pairs fit the gains (their N x N cosines at each step)
TOLERANCE = 2       # references within this many places of a frame's own count as its place


def contrastive_loss(theta: np.ndarray, q: np.ndarray, r: np.ndarray, groups: np.ndarray, near: np.ndarray,
                     tau: float = TAU, reg: float = GAIN_REG) -> tuple[float, np.ndarray]:
    """The loss (module docstring) and its gradient in ``theta`` (G,): pairs' frames ``q`` and references
    ``r`` (N, D), each dimension's group ``groups`` (D,) in 0..G-1, ``near`` (N, N) bool: pair j's reference
    lies within the tolerance of pair i's place (every row holds its own pair)."""
    n = len(q)
    w = np.exp(theta)[groups]
    nq, nr = np.sqrt((q * q) @ w), np.sqrt((r * r) @ w)
    s = ((q * w) @ r.T) / np.outer(nq, nr)
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
    h = grad_s / np.outer(nq, nr)
    gw = (q * (h @ r)).sum(axis=0)
    gs = grad_s * s
    gw -= 0.5 * ((gs.sum(axis=1) / nq ** 2) @ (q * q) + (gs.sum(axis=0) / nr ** 2) @ (r * r))
    grad = np.bincount(groups, weights=gw * w, minlength=len(theta))
    return loss + reg * float(theta @ theta) / len(theta), grad + 2.0 * reg * theta / len(theta)


def fit_gains(queries: np.ndarray, refs: np.ndarray, places: np.ndarray, groups: np.ndarray, tau: float = TAU,
              reg: float = GAIN_REG, tolerance: int = TOLERANCE, max_pairs: int = GAIN_PAIRS,
              seed: int = 0) -> np.ndarray:
    """Labelled frames' encodings ``queries`` and their references ``refs`` (N, D), each pair's place
    ``places`` (N,), the dimensions' ``groups`` (D,) -> each dimension's gain (D,) float64, sqrt(w) (the
    encodings are scaled by it, so cosines weigh w). Each set is centred first (the cosine the
    standardised matching reads); over ``max_pairs`` pairs a seeded sample fits."""
    from scipy.optimize import minimize

    q = np.asarray(queries, np.float64)
    r = np.asarray(refs, np.float64)
    places = np.asarray(places, np.int64)
    if len(q) > max_pairs:
        keep = np.sort(np.random.default_rng(seed).choice(len(q), max_pairs, replace=False))
        q, r, places = q[keep], r[keep], places[keep]
    q, r = q - q.mean(axis=0), r - r.mean(axis=0)
    near = np.abs(places[:, None] - places[None, :]) <= tolerance
    n_groups = int(groups.max()) + 1
    res = minimize(contrastive_loss, np.zeros(n_groups), args=(q, r, groups, near, tau, reg), jac=True,
                   method="L-BFGS-B", options={"maxiter": 200})
    return np.sqrt(np.exp(res.x))[groups]
