"""Coarse whole-route similarities: signs and Hamming distances against plain loops, exact values where the
search keeps them, the calibration line elsewhere, and the Localizer's whole-route frames through it."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vpr_edge.index.coarse import CoarseSearch, hamming, pack_signs
from vpr_edge.index.encodings import Encodings


@pytest.mark.parametrize("d", [64, 100, 2048])
def test_signs_and_hamming_against_plain_loops(d: int, monkeypatch: pytest.MonkeyPatch) -> None:
    import vpr_edge.index.coarse as coarse

    rng = np.random.default_rng(d)
    x = rng.normal(size=(37, d)).astype(np.float32)
    x[3, : d // 2] = 0.0                                  # zeros count as negative (bit clear)
    q = rng.normal(size=d).astype(np.float32)
    monkeypatch.setattr(coarse, "SIGN_BLOCK", 5)          # several blocks and a short last one
    got = hamming(pack_signs(x), pack_signs(q[None])[0])
    naive = [sum((float(a) > 0) != (float(b) > 0) for a, b in zip(row, q)) for row in x]
    assert got.tolist() == naive


def test_similarity_exact_where_kept_calibrated_elsewhere() -> None:
    rng = np.random.default_rng(0)
    refs = rng.normal(size=(3000, 256)).astype(np.float32)
    refs /= np.linalg.norm(refs, axis=1, keepdims=True)
    stored = Encodings.pack(refs, "int8")
    search = CoarseSearch(stored, keep=50, calib=200, seed=1)
    q = stored.dense_row(1234) + 0.05 * rng.normal(size=256).astype(np.float32)
    row = search.similarity(q)
    exact = stored.similarity(q[None])[0]
    est = search.agreement(q)
    naive_est = np.array([np.mean((r > 0) == (q > 0)) * 2 - 1 for r in stored.values.astype(np.float32)])
    np.testing.assert_allclose(est, naive_est, atol=1e-6)  # a stored 0 counts as negative
    top = np.argsort(-est, kind="stable")[:50]
    kept = np.union1d(top, search.calib)
    np.testing.assert_allclose(row[kept], exact[kept], atol=1e-6)
    x, y = est[search.calib], exact[search.calib]
    rest = np.setdiff1d(np.arange(3000), kept)
    np.testing.assert_allclose(row[rest], y.mean() + (est[rest] - x.mean()) * y.std() / x.std(), atol=1e-5)
    assert int(np.argmax(row)) == int(np.argmax(exact)) == 1234
    # the row is on the exact scale: same mean and spread within 10%
    assert abs(row.mean() - exact.mean()) < 0.1 * exact.std() and abs(row.std() / exact.std() - 1) < 0.1


@pytest.mark.slow
def test_localizer_whole_route_frames_go_through_it(api_map_small: Path, small_queries: Path) -> None:
    """Forced on the 24-place map (keep >= R: every value exact), the answers are those without it, and
    every frame went through the coarse search (the local search does not engage on 24 places)."""
    from vpr_edge import Localizer
    from vpr_edge.frames.images import load_image

    files = sorted(small_queries.iterdir())
    plain = Localizer(api_map_small, threads=1)
    coarse = Localizer(api_map_small, threads=1, coarse=True)
    assert plain._search.coarse is None and coarse._search.coarse is not None
    calls = []
    real = coarse._search.coarse.similarity
    coarse._search.coarse.similarity = lambda q: calls.append(1) or real(q)   # type: ignore[method-assign]
    a = [plain.push(load_image(f)) for f in files]
    b = [coarse.push(load_image(f)) for f in files]
    assert len(calls) == len(files)
    assert [m.ref_index for m in a] == [m.ref_index for m in b]
    np.testing.assert_allclose([m.score for m in a], [m.score for m in b], atol=1e-5)


@pytest.fixture(scope="module")
def api_map_small(tmp_path_factory: pytest.TempPathFactory, small_refs: Path) -> Path:
    from typer.testing import CliRunner

    from vpr_edge.cli import app

    out = tmp_path_factory.mktemp("coarse") / "m.npz"
    res = CliRunner().invoke(app, ["build-map", str(small_refs), "-o", str(out), "--components", "4", "--pca-dim", "0"])
    assert res.exit_code == 0, res.output
    return out


def _rss_file_mb() -> float | None:
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("RssFile:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return None


@pytest.mark.slow
def test_sign_pass_releases_a_memory_mapped_map(tmp_path: Path) -> None:
    """Packing the signs reads every stored row; on a memory-mapped map those pages are then dropped from
    the process (store.release_pages), the values still read the same, and an in-RAM map is left alone."""
    from vpr_edge.files.npz import read_npz, write_npz
    from vpr_edge.index.rows import release_pages

    rng = np.random.default_rng(1)
    stored = Encodings.pack(rng.normal(size=(16_000, 1024)).astype(np.float32), "int8")   # 16 MB
    write_npz(tmp_path / "m.npz", stored.to_arrays(), {"kind": "test map", "schema": 1})
    mapped = Encodings.from_arrays(read_npz(tmp_path / "m.npz", "test map", 1, mmap=True)[0], "int8")
    before = _rss_file_mb()
    coarse = CoarseSearch(mapped)
    np.testing.assert_array_equal(coarse.signs, CoarseSearch(stored).signs)
    after = _rss_file_mb()
    if before is not None:   # Linux: the pass did not leave the map's 16 MB resident
        assert after - before < 8.0
        int(np.asarray(mapped.values).sum(dtype=np.int64))        # touch every page again
        assert _rss_file_mb() - before > 8.0
        assert release_pages(mapped.values[:8000])                 # a view: the pages it spans (8 MB)
        assert 4.0 < _rss_file_mb() - before < 12.0
        assert release_pages(mapped.values)                        # the whole mapping
        assert _rss_file_mb() - before < 4.0
        mapped.similarity(rng.normal(size=(1, 1024)))              # a whole-route pass, block by block
        assert _rss_file_mb() - before < 4.0
        rows = rng.choice(16_000, 3000, replace=False)             # scattered rows: read, not mapped
        np.testing.assert_array_equal(mapped.take(rows), stored.values[rows])
        assert _rss_file_mb() - before < 4.0
    np.testing.assert_array_equal(mapped.values[5000], stored.values[5000])
    assert not release_pages(stored.values)


@pytest.mark.parametrize("cache_rows", [8, 64, 10_000])
def test_row_reader_against_the_array(tmp_path: Path, cache_rows: int) -> None:
    """RowReader.take equals plain indexing for runs, scattered rows, repeats and any order, whatever the
    cache's size (a small cache evicts between and within calls), for every stored dtype."""
    from vpr_edge.index.rows import RowReader
    from vpr_edge.files.npz import read_npz, write_npz

    rng = np.random.default_rng(cache_rows)
    for dtype in (np.int8, np.float16, np.float32):
        x = (rng.normal(size=(500, 33)) * 50).astype(dtype)
        write_npz(tmp_path / "a.npz", {"x": x}, {"kind": "test", "schema": 1})
        mapped = read_npz(tmp_path / "a.npz", "test", 1, mmap=True)[0]["x"]
        reader = RowReader(mapped, cache_bytes=0, min_rows=cache_rows)
        asks = [np.arange(100, 301), rng.integers(0, 500, 50), np.array([7, 7, 3, 499, 0, 8, 9, 10]),
                rng.permutation(500), np.arange(0), np.arange(250, 260)[::-1]]
        for _ in range(3):
            for idx in asks:
                np.testing.assert_array_equal(reader.take(idx), x[idx])
        assert reader.take(np.arange(0)).shape == (0, 33)
        np.testing.assert_array_equal(reader.take(np.array([-1, -500])), x[[-1, -500]])
        with pytest.raises(IndexError):
            reader.take(np.array([500]))


def test_agreement_and_bytes_against_loops() -> None:
    """Sign agreement against a loop over dimensions (zero counts as negative, as ``pack_signs`` sets bits),
    and the bytes a place each storage keeps."""
    from vpr_edge.index.coarse import agreement, sign_bytes
    from vpr_edge.index.encodings import Encodings, bytes_per_place

    rng = np.random.default_rng(3)
    refs, queries = rng.normal(size=(7, 70)), rng.normal(size=(3, 70))
    refs[0, :5] = 0.0
    want = [[np.mean([1.0 if (q[d] > 0) == (r[d] > 0) else -1.0 for d in range(70)]) for r in refs] for q in queries]
    np.testing.assert_allclose(agreement(refs, queries), want, atol=1e-6)
    assert sign_bytes(70) == 9 and [bytes_per_place(70, s) for s in ("float32", "float16", "int8")] == [280, 140, 74]
    assert Encodings.pack(refs.astype(np.float32), "int8").bytes_per_place == 74
