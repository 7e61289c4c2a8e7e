"""Encoders against naive per-descriptor, per-component references; codebook fitting (scikit-learn) and the
no-pickle .npz + JSON storage."""
from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest

from vpr_edge.encoders import ENCODERS, FitSettings, encoder_from_arrays, fit_encoder, load_codebook
from vpr_edge.encoders.base import Pca
from vpr_edge.encoders.fisher import FisherVector, Gmm, ImprovedFisherVector
from vpr_edge.encoders.flat import Flatten
from vpr_edge.encoders.words import BagOfWords, Vlad
from vpr_edge.errors import VprError
from vpr_edge.files.npz import META_KEY, read_npz, write_npz


def random_pca(rng: np.random.Generator, d: int, k: int) -> Pca:
    return Pca(rng.normal(size=d), np.linalg.qr(rng.normal(size=(d, k)))[0].T, rng.random(k) + 0.5)


def random_gmm(rng: np.random.Generator, m: int = 5, k: int = 4) -> Gmm:
    w = rng.random(m) + 0.2
    return Gmm(w / w.sum(), rng.normal(size=(m, k)), rng.random((m, k)) + 0.3)


# ------------------------------------------------------------------ naive references, one descriptor at a time
def naive_project(x: np.ndarray, pca: Pca | None) -> np.ndarray:
    if pca is None:
        return x.astype(np.float64)
    return np.array([[(row - pca.mean) @ pca.components[j] / pca.scale[j] for j in range(len(pca.scale))]
                     for row in x])


def naive_posteriors(x: np.ndarray, gmm: Gmm) -> np.ndarray:
    dens = np.zeros((len(x), gmm.n_components))
    for n in range(len(x)):
        for c in range(gmm.n_components):
            var = gmm.variances[c]
            dens[n, c] = gmm.weights[c] * np.prod(np.exp(-0.5 * (x[n] - gmm.means[c]) ** 2 / var)
                                                  / np.sqrt(2 * np.pi * var))
    return dens / dens.sum(axis=1, keepdims=True)


def naive_power_l2(v: np.ndarray, alpha: float) -> np.ndarray:
    v = np.array([np.sign(t) * abs(t) ** alpha for t in v])
    return v / np.sqrt(sum(t * t for t in v))


def naive_fisher(x: np.ndarray, gmm: Gmm, pca: Pca | None, alpha: float) -> np.ndarray:
    y = naive_project(x, pca)
    post = naive_posteriors(y, gmm)
    n = len(y)
    mu_part, sig_part = [], []
    for c in range(gmm.n_components):
        sd = np.sqrt(gmm.variances[c])
        gm, gs = np.zeros(gmm.dim), np.zeros(gmm.dim)
        for i in range(n):
            z = (y[i] - gmm.means[c]) / sd
            gm += post[i, c] * z
            gs += post[i, c] * (z * z - 1)
        mu_part.append(gm / (n * np.sqrt(gmm.weights[c])))
        sig_part.append(gs / (n * np.sqrt(2 * gmm.weights[c])))
    return naive_power_l2(np.concatenate(mu_part + sig_part), alpha)


def naive_nearest(y: np.ndarray, centres: np.ndarray) -> list[int]:
    return [int(np.argmin([np.sum((row - c) ** 2) for c in centres])) for row in y]


def naive_bow(x: np.ndarray, centres: np.ndarray, pca: Pca | None, idf: np.ndarray | None) -> np.ndarray:
    counts = np.zeros(len(centres))
    for c in naive_nearest(naive_project(x, pca), centres):
        counts[c] += 1
    tf = counts / len(x)
    return naive_power_l2(tf * idf if idf is not None else tf, 1.0)


def naive_vlad(x: np.ndarray, centres: np.ndarray, pca: Pca | None, alpha: float) -> np.ndarray:
    y = naive_project(x, pca)
    v = np.zeros_like(centres)
    for row, c in zip(y, naive_nearest(y, centres)):
        v[c] += row - centres[c]
    for c in range(len(centres)):
        norm = np.sqrt(np.sum(v[c] ** 2))
        if norm > 0:
            v[c] /= norm
    return naive_power_l2(v.reshape(-1), alpha)


# -------------------------------------------------------------------------------------------------- tests
def test_posteriors_match_direct_densities() -> None:
    rng = np.random.default_rng(1)
    gmm = random_gmm(rng)
    x = rng.normal(size=(30, 4))
    got = np.exp(gmm.log_responsibilities(x))
    np.testing.assert_allclose(got, naive_posteriors(x, gmm), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(got.sum(axis=1), 1.0)


def test_posteriors_stable_far_from_all_components() -> None:
    gmm = random_gmm(np.random.default_rng(2))
    post = np.exp(gmm.log_responsibilities(np.full((3, 4), 1e3)))
    assert np.all(np.isfinite(post))
    np.testing.assert_allclose(post.sum(axis=1), 1.0)


@pytest.mark.parametrize("improved", [True, False])
@pytest.mark.parametrize("pca_dim", [None, 7])
def test_fisher_vectors_match_naive(improved: bool, pca_dim: int | None) -> None:
    rng = np.random.default_rng(3)
    gmm = random_gmm(rng, m=5, k=4)
    pca = random_pca(rng, pca_dim, 4) if pca_dim else None
    d = pca_dim or 4
    enc = ImprovedFisherVector(gmm, pca, d, 0.5) if improved else FisherVector(gmm, pca, d)
    x = rng.normal(size=(3, 20, d))
    got = enc.transform(x)
    assert got.shape == (3, 2 * 5 * 4) == (3, enc.dim) and got.dtype == np.float32
    for b in range(3):
        np.testing.assert_allclose(got[b], naive_fisher(x[b], gmm, pca, 0.5 if improved else 1.0),
                                   rtol=2e-5, atol=2e-6)
    np.testing.assert_allclose(np.linalg.norm(got, axis=1), 1.0, rtol=1e-5)


@pytest.mark.parametrize("tfidf", [False, True])
@pytest.mark.parametrize("pca_dim", [None, 3])
def test_bow_matches_naive(tfidf: bool, pca_dim: int | None) -> None:
    rng = np.random.default_rng(5)
    centres = rng.normal(size=(6, 3))
    pca = random_pca(rng, pca_dim + 2, 3) if pca_dim else None
    d = pca.components.shape[1] if pca else 3
    idf = rng.random(6) + 0.1 if tfidf else None
    enc = BagOfWords(centres, pca, d, idf)
    x = rng.normal(size=(4, 25, d))
    got = enc.transform(x)
    assert got.shape == (4, 6) == (4, enc.dim)
    for b in range(4):
        np.testing.assert_allclose(got[b], naive_bow(x[b], centres, pca, idf), rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("alpha", [0.5, 1.0])
def test_vlad_matches_naive(alpha: float) -> None:
    rng = np.random.default_rng(6)
    centres = rng.normal(size=(5, 4))
    enc = Vlad(centres, None, 4, alpha)
    x = rng.normal(size=(3, 30, 4))
    x[2, :, :] = centres[0] + 0.01 * rng.normal(size=(30, 4))    # every descriptor on one centre: others empty
    got = enc.transform(x)
    assert got.shape == (3, 20) == (3, enc.dim)
    for b in range(3):
        np.testing.assert_allclose(got[b], naive_vlad(x[b], centres, None, alpha), rtol=1e-5, atol=1e-6)


def test_none_flattens_in_grid_order() -> None:
    x = np.random.default_rng(7).normal(size=(2, 6, 3))
    got = Flatten(3, 6).transform(x)
    for b in range(2):
        np.testing.assert_allclose(got[b], x[b].reshape(-1) / np.linalg.norm(x[b]), rtol=1e-6)
    with pytest.raises(VprError, match="expects 6 descriptors"):
        Flatten(3, 6).transform(x[:, :5])
    mask = np.arange(6)[None].repeat(len(x), 0) % 2 == 0          # a padded frame's border cells: zeros
    kept = np.where(mask[..., None], x, 0.0)
    np.testing.assert_allclose(Flatten(3, 6).transform(x, mask), Flatten(3, 6).transform(kept), rtol=1e-6)


@pytest.mark.parametrize("name", ["bow", "vlad", "fv", "ifv"])
def test_mask_drops_padding_exactly(name: str) -> None:
    """A padded, masked set encodes as the same set without padding (detected keypoints)."""
    rng = np.random.default_rng(8)
    x = rng.normal(size=(1, 12, 4))
    local = rng.normal(size=(40, 10, 4))
    enc = fit_encoder(name, local, None, FitSettings(n_components=3, max_descriptors=400), 10)
    padded = np.concatenate([x, rng.normal(size=(1, 5, 4)) * 50], axis=1)
    mask = np.arange(17)[None] < 12
    np.testing.assert_allclose(enc.transform(padded, mask), enc.transform(x), rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("name", list(ENCODERS))
def test_every_encoder_roundtrips_through_arrays_and_json(tmp_path, name: str) -> None:
    rng = np.random.default_rng(9)
    local = rng.normal(size=(30, 8, 5)).astype(np.float32)
    enc = fit_encoder(name, local, None, FitSettings(n_components=4, pca_dim=3 if name != "none" else None,
                                                     tfidf=True), 8)
    path = tmp_path / "cb.npz"
    enc.save(path)
    with np.load(path, allow_pickle=False) as z:   # readable with pickle disabled
        assert json.loads(str(z[META_KEY]))["encoding"]["name"] == name
    back, meta = load_codebook(path)
    assert type(back) is type(enc) and back.params() == enc.params() and meta["input_dim"] == 5
    np.testing.assert_array_equal(back.transform(local[:3]), enc.transform(local[:3]))
    assert enc.transform(local[:3]).shape == (3, enc.dim)
    with pytest.raises(VprError, match="expects 5-dim descriptors"):
        enc.transform(local[:2, :, :4])
    if enc.to_arrays():
        broken = {k: v[:-1] for k, v in enc.to_arrays().items()}
        with pytest.raises(VprError, match="cb.npz: codebook arrays are inconsistent|missing"):
            encoder_from_arrays({"name": name, "params": enc.params()}, broken, 5, "cb.npz")


def test_schema_1_codebook_reads_as_ifv(tmp_path) -> None:
    rng = np.random.default_rng(10)
    gmm = random_gmm(rng, 3, 4)
    write_npz(tmp_path / "old.npz", {"gmm_weights": gmm.weights, "gmm_means": gmm.means,
                                     "gmm_variances": gmm.variances},
              {"kind": "codebook", "schema": 1, "input_dim": 4, "n_components": 3, "pca_dim": None})
    enc, _ = load_codebook(tmp_path / "old.npz")
    assert enc.name == "ifv" and enc.dim == 24


@pytest.fixture(scope="module")
def clustered() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    centres = rng.normal(scale=8.0, size=(4, 6))
    labels = rng.integers(0, 4, size=4000)
    return (centres[labels] + rng.normal(size=(4000, 6))).reshape(400, 10, 6), centres


@pytest.mark.parametrize("name", ["ifv", "vlad"])
def test_fit_recovers_clusters(clustered: tuple[np.ndarray, np.ndarray], name: str) -> None:
    local, centres = clustered
    enc = fit_encoder(name, local, None, FitSettings(n_components=4), 10)
    found = enc.gmm.means if name == "ifv" else enc.centres
    dist = np.linalg.norm(found[:, None] - centres[None], axis=2)
    assert np.all(dist.min(axis=0) < 0.3)
    if name == "ifv":
        np.testing.assert_allclose(enc.gmm.weights.sum(), 1.0)
        np.testing.assert_allclose(enc.gmm.variances, 1.0, atol=0.2)


def test_fit_with_whitened_pca(clustered: tuple[np.ndarray, np.ndarray]) -> None:
    local, _ = clustered
    enc = fit_encoder("ifv", local, None, FitSettings(n_components=4, pca_dim=3, whiten=True), 10)
    y = enc.project(local.reshape(-1, 6))
    assert y.shape == (4000, 3)
    np.testing.assert_allclose(y.mean(axis=0), 0.0, atol=1e-6)
    np.testing.assert_allclose(y.var(axis=0), 1.0, rtol=0.01)


def test_fit_survives_identical_descriptors() -> None:
    """A third of the descriptors identical (flat regions: HOG of a uniform sky, as on nordland-dev): a GMM
    component collapses onto them and scikit-learn's float32 EM fails; the fit goes on in float64 and finds the
    cluster, with a tiny but positive variance."""
    rng = np.random.default_rng(12)
    x = rng.normal(size=(6000, 8)) + 5.0
    x[:2000] = x[0]
    enc = fit_encoder("ifv", x.reshape(600, 10, 8), None, FitSettings(n_components=8), 10)
    gmm = enc.gmm
    assert np.all(np.isfinite(gmm.means)) and np.all(gmm.variances > 0)
    np.testing.assert_allclose(gmm.weights.sum(), 1.0)
    near = np.linalg.norm(gmm.means - x[0], axis=1).argmin()
    assert np.linalg.norm(gmm.means[near] - x[0]) < 1e-3 and gmm.variances[near].max() < 1e-3
    assert gmm.weights[near] > 0.3


def test_idf_counts_reference_images_holding_each_word() -> None:
    rng = np.random.default_rng(11)
    local = rng.normal(size=(20, 6, 2))
    enc = fit_encoder("bow", local, None, FitSettings(n_components=4, tfidf=True), 6)
    words = [set(naive_nearest(img, enc.centres)) for img in local]
    df = np.array([sum(c in w for w in words) for c in range(4)])
    np.testing.assert_allclose(enc.idf, np.log(21 / (1 + df)))


@pytest.mark.parametrize("name", ["bow", "ifv"])
def test_fit_refuses_too_few_descriptors(name: str) -> None:
    with pytest.raises(VprError, match="too few"):
        fit_encoder(name, np.zeros((10, 10, 3)), None, FitSettings(n_components=128), 10)


def test_none_refuses_keypoint_front_ends() -> None:
    with pytest.raises(VprError, match="fixed grid"):
        fit_encoder("none", np.zeros((2, 3, 4)), np.ones((2, 3), bool), FitSettings(), None)


def test_storage_errors(tmp_path) -> None:
    path = tmp_path / "x.npz"
    write_npz(path, {"a": np.arange(3)}, {"kind": "codebook", "schema": 99})
    with pytest.raises(VprError, match=r"made by a newer vpr-edge \(codebook schema 99, this one reads up to 1\): "
                                       "upgrade vpr-edge"):
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
