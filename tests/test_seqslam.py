"""SeqSLAM (offline and online) and its local contrast against plain loops."""
from __future__ import annotations

import numpy as np
import pytest

from helpers import planted
from vpr_edge.matchers.contrast import local_contrast
from vpr_edge.matchers.seqslam import SeqSLAMOnline, enhanced_difference, seqslam_match, speeds


def naive_contrast(sim: np.ndarray, window: int) -> np.ndarray:
    out = np.empty_like(sim, dtype=float)
    r = sim.shape[1]
    for i in range(sim.shape[0]):
        for j in range(r):
            w = sim[i, max(0, j - window // 2): min(r, j + window // 2 + 1)]
            out[i, j] = (sim[i, j] - w.mean()) / np.sqrt(w.var() + 1e-12)
    return out


def naive_seqslam(sim, ds, vmin, vmax, r_window, match_window, online):
    d = -naive_contrast(sim, r_window)
    q, r = d.shape
    v = speeds(ds, vmin, vmax)
    refs, scores = [], []
    if not online:
        d = d - d.min()
    for n in range(q):
        values, pos = [], []
        for s in range(r):
            best, best_pos = np.inf, 0
            for vel in v:
                total = 0.0
                if online:
                    frames = range(max(0, n - ds), n + 1)
                    for x in frames:
                        row = d[x] - d[x].min()
                        total += row[max(s - int(np.floor((n - x) * vel + 1e-9)), 0)]
                    p = s
                else:
                    length = min(ds + 1, q)
                    x0 = min(max(n - ds // 2, 0), q - length)
                    for k in range(length):
                        total += d[x0 + k, min(s + int(np.floor(k * vel + 1e-9)), r - 1)]
                    p = min(s + int(np.floor((n - x0) * vel + 1e-9)), r - 1)
                if total < best:
                    best, best_pos = total, p
            values.append(best)
            pos.append(best_pos)
        values = np.array(values)
        s = int(np.argmin(values))
        far = np.abs(np.arange(r) - s) > match_window // 2
        refs.append(pos[s])
        scores.append(1 - values[s] / values[far].min())
    return np.array(refs), np.array(scores)


def test_local_contrast_matches_loop() -> None:
    sim = np.random.default_rng(0).normal(size=(4, 23))
    for w in (2, 5, 10):
        np.testing.assert_allclose(local_contrast(sim, w), naive_contrast(sim, w), atol=1e-9)


@pytest.mark.parametrize("online", [False, True])
def test_seqslam_matches_plain_loops(online: bool) -> None:
    rng = np.random.default_rng(1)
    places = np.clip(np.round(np.cumsum(rng.uniform(0.5, 2.0, 16))).astype(int), 0, 39)
    sim = planted(rng, 40, places, noise=0.3)
    params = {"ds": 4, "vmin": 0.5, "vmax": 2.0, "r_window": 6, "match_window": 6}
    want_refs, want_scores = naive_seqslam(sim, online=online, **params)
    if online:
        m = SeqSLAMOnline(40, **params)
        got = np.array([m.update(row) for row in sim])
        got_refs, got_scores = got[:, 0].astype(int), got[:, 1]
    else:
        res = seqslam_match(sim, **params)
        got_refs, got_scores = res.refs, res.scores
    np.testing.assert_array_equal(got_refs, want_refs)
    np.testing.assert_allclose(got_scores, want_scores, atol=1e-9)
    assert np.mean(np.abs(got_refs - places) <= 1) > 0.7


def test_seqslam_difference_is_non_negative() -> None:
    d = enhanced_difference(np.random.default_rng(2).normal(size=(5, 30)), r_window=10)
    assert d.min() == 0.0
