"""Descriptor standardisation (``encoders.standardise``) against plain loops."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from helpers import invoke

from vpr_edge.encoders.standardise import RouteMean, StreamMean, centred_stream


def _unit(x: np.ndarray) -> np.ndarray:
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def test_the_running_mean_is_a_plain_loops() -> None:
    rng = np.random.default_rng(0)
    prior, q = rng.normal(size=6), rng.normal(size=(40, 6))
    got = centred_stream(q, prior, prior_frames=5.0, horizon=10.0)
    keep, total, weight = 0.9, 5.0 * prior, 5.0
    for t in range(40):
        u = q[t] / np.linalg.norm(q[t])
        np.testing.assert_allclose(got[t], u - total / weight, rtol=1e-5, atol=1e-6)
        total, weight = total * keep + u, weight * keep + 1.0
    first = StreamMean(prior, 5.0, 10.0)
    np.testing.assert_allclose(first.centre(q[0]), got[0], rtol=1e-6)   # the first frame: the prior's mean


def test_scores_are_the_cosines_of_the_standardised_pair() -> None:
    rng = np.random.default_rng(1)
    refs = rng.normal(size=(30, 8)) + 2.0          # a common offset: what standardisation takes away
    scaled = refs * rng.uniform(0.5, 3.0, size=(30, 1))   # stored rows of any positive scale (int8's)
    stats = RouteMean.of(lambda: iter([scaled[:7], scaled[7:]]))
    units = _unit(refs)
    np.testing.assert_allclose(stats.mean, units.mean(axis=0), rtol=1e-5)
    q = rng.normal(size=(4, 8)) + 2.0
    centred = _unit(q) - units.mean(axis=0)        # a stream whose mean is the references'
    rows = np.array([3, 0, 29])
    got = stats.scores(centred @ units[rows].T, centred, rows)
    for b in range(4):
        for j, r in enumerate(rows):
            a, c = units[r] - units.mean(axis=0), centred[b]
            assert got[b, j] == pytest.approx(a @ c / (np.linalg.norm(a) * np.linalg.norm(c)), rel=1e-4)
    every = stats.scores(centred @ units.T, centred)
    np.testing.assert_allclose(every[:, rows], got, rtol=1e-5)


def test_a_shared_offset_no_longer_hides_the_place() -> None:
    """Places told apart by small differences on top of what a whole drive shares, and a query drive with an
    offset of its own (another season): once the stream's mean has followed it, the standardised cosine
    finds the place far more often than the raw one."""
    rng = np.random.default_rng(2)
    places = rng.normal(size=(300, 16))
    refs = places + 6.0 * np.ones(16)
    queries = places[:200] + 0.3 * rng.normal(size=(200, 16)) + 6.0 * np.ones(16) + 3.0 * rng.normal(size=16)
    stats = RouteMean.of(lambda: iter([refs]))
    centred = centred_stream(queries, stats.mean)
    std = stats.scores(centred @ _unit(refs).T, centred)[100:]
    raw = (_unit(queries) @ _unit(refs).T)[100:]
    truth = np.arange(100, 200)
    assert (std.argmax(axis=1) == truth).mean() >= 0.6 > 0.1 >= (raw.argmax(axis=1) == truth).mean()   # 0.71, 0.01


def test_bad_settings_and_an_empty_route_are_refused() -> None:
    with pytest.raises(ValueError, match="prior_frames"):
        StreamMean(np.zeros(3), prior_frames=0)
    with pytest.raises(ValueError, match="no references"):
        RouteMean.of(lambda: iter([]))


def test_a_streams_frames_read_what_the_whole_stream_reads() -> None:
    """``map.search.FrameSearch`` frame by frame (``localize``) gives the rows of ``evaluation.sources``'
    whole-stream matrix (``evaluate``), window rows included, and forgets the stream on reset."""
    from types import SimpleNamespace

    from vpr_edge.evaluation.sources import standardised
    from vpr_edge.map.search import FrameSearch

    rng = np.random.default_rng(3)
    refs = _unit(rng.normal(size=(40, 12)) + 1.5).astype(np.float32)
    route = RouteMean.of(lambda: iter([refs]))
    query = SimpleNamespace(map=SimpleNamespace(route_mean=route, index=None),
                            scores=lambda q, kind="cosine", rows=None: q @ (refs if rows is None else refs[rows]).T)
    enc = rng.normal(size=(25, 12)).astype(np.float32) + 1.0
    whole = standardised(query, enc)
    search = FrameSearch(query, "cosine", 1, None, standardise=True)
    window = np.arange(5, 15)
    for _ in range(2):
        for i, e in enumerate(enc):
            search.push(e)
            np.testing.assert_allclose(search.rows(None), whole[i], rtol=1e-4, atol=1e-5)
            np.testing.assert_allclose(search.rows(window), whole[i, window], rtol=1e-4, atol=1e-5)
        search.reset()
    raw = FrameSearch(query, "cosine", 1, None, standardise=False)
    raw.push(enc[0])
    np.testing.assert_allclose(raw.rows(None), enc[0] @ refs.T, rtol=1e-5)


def test_build_map_stores_the_statistics_and_load_checks_them(tmp_path: Path, small_refs: Path) -> None:
    """build-map writes the references' mean and spread; a map without them computes the same on first use;
    a spread that does not fit the encodings is one line naming the file."""
    from vpr_edge.errors import VprError
    from vpr_edge.files.npz import read_npz, write_npz
    from vpr_edge.map import load_map

    out = tmp_path / "ldb.npz"
    assert invoke("build-map", small_refs, "-o", out, "--features", "ldb", "--encoding", "none")[0] == 0
    held = load_map(out)
    assert held.stored_mean is not None
    fresh = RouteMean.of(held.stored.in_order)
    np.testing.assert_allclose(held.route_mean.mean, fresh.mean, atol=1e-6)
    np.testing.assert_allclose(held.route_mean.spread, fresh.spread, atol=1e-6)
    arrays, meta = read_npz(out, "map", meta_schema := int(load_map(out).meta["schema"]))
    older = {k: v for k, v in arrays.items() if not k.startswith("route_")}
    write_npz(tmp_path / "older.npz", older, meta)
    old = load_map(tmp_path / "older.npz")
    assert old.stored_mean is None and np.allclose(old.route_mean.spread, fresh.spread, atol=1e-6)
    write_npz(tmp_path / "bad.npz", arrays | {"route_spread": arrays["route_spread"][:-1]}, meta)
    with pytest.raises(VprError, match=r"bad\.npz: map is inconsistent \(the references' mean") as e:
        load_map(tmp_path / "bad.npz")
    assert "\n" not in str(e.value) and meta_schema >= 4
