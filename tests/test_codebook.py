"""Codebook fitting (scikit-learn) and the no-pickle .npz + JSON storage."""
from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest

from vpr_edge.codebook import Codebook
from vpr_edge.errors import VprError
from vpr_edge.store import META_KEY, read_npz, write_npz
from vpr_edge_export.codebook_fit import fit_codebook


@pytest.fixture(scope="module")
def clustered() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    centres = rng.normal(scale=8.0, size=(4, 6))
    labels = rng.integers(0, 4, size=4000)
    return centres[labels] + rng.normal(size=(4000, 6)), centres


def test_fit_recovers_clusters(clustered: tuple[np.ndarray, np.ndarray]) -> None:
    x, centres = clustered
    cb = fit_codebook(x, n_components=4)
    dist = np.linalg.norm(cb.gmm.means[:, None] - centres[None], axis=2)
    assert np.all(dist.min(axis=0) < 0.3)
    np.testing.assert_allclose(cb.gmm.weights.sum(), 1.0)
    np.testing.assert_allclose(cb.gmm.variances, 1.0, atol=0.2)


def test_fit_with_whitened_pca(clustered: tuple[np.ndarray, np.ndarray]) -> None:
    x, _ = clustered
    cb = fit_codebook(x, n_components=4, pca_dim=3, whiten=True)
    y = cb.project(x)
    assert y.shape == (4000, 3)
    np.testing.assert_allclose(y.mean(axis=0), 0.0, atol=1e-6)
    np.testing.assert_allclose(y.var(axis=0), 1.0, rtol=0.01)


def test_fit_refuses_too_few_descriptors() -> None:
    with pytest.raises(VprError, match="too few"):
        fit_codebook(np.zeros((100, 3)), n_components=128)


def test_roundtrip_without_pickle(tmp_path, clustered) -> None:
    x, _ = clustered
    cb = fit_codebook(x, n_components=4, pca_dim=5)
    path = tmp_path / "cb.npz"
    cb.save(path)
    with np.load(path, allow_pickle=False) as z:   # readable with pickle disabled
        assert json.loads(str(z[META_KEY]))["schema"] == 1
    back, meta = Codebook.load(path)
    for a, b in zip(cb.to_arrays().values(), back.to_arrays().values()):
        np.testing.assert_array_equal(a, b)
    assert meta["n_components"] == 4 and meta["pca_dim"] == 5


def test_storage_errors(tmp_path) -> None:
    path = tmp_path / "x.npz"
    write_npz(path, {"a": np.arange(3)}, {"kind": "codebook", "schema": 99})
    with pytest.raises(VprError, match="schema version 99"):
        read_npz(path, "codebook", 1)
    with pytest.raises(VprError, match=r"not a vpr-edge map \(it is a vpr-edge codebook\)"):
        read_npz(path, "map", 99)
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"not a zip at all")
    with pytest.raises(VprError, match=r"garbage.npz: not a vpr-edge map \(a text file"):
        read_npz(garbage, "map", 1)
    with zipfile.ZipFile(tmp_path / "nometa.npz", "w") as z:
        z.writestr("a.npy", b"")
    with pytest.raises(VprError):
        read_npz(tmp_path / "nometa.npz", "map", 1)
    with pytest.raises(ValueError, match="pickle"):
        write_npz(path, {"o": np.array([{}], dtype=object)}, {})


def test_atomic_write_keeps_old_file_on_failure(tmp_path) -> None:
    path = tmp_path / "m.npz"
    write_npz(path, {"a": np.arange(3)}, {"kind": "t", "schema": 1})
    before = path.read_bytes()
    with pytest.raises(ValueError):
        write_npz(path, {"o": np.array([object()], dtype=object)}, {"kind": "t", "schema": 1})

    class Exploding:
        def __array__(self, *a, **k):
            raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        write_npz(path, {"a": Exploding()}, {"kind": "t", "schema": 1})  # type: ignore[dict-item]
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.npz"]   # no temp file left behind
