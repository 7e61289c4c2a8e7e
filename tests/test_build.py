"""The build pipeline: each reference image described once, the codebook fitted on a pool of references
(all of them on small routes), every reference encoded as it is extracted and stored packed, append
without expanding stored rows."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import vpr_edge.map.build as mapfile
from vpr_edge.index.encodings import EncodingWriter, Encodings, STORAGES
from vpr_edge.encoders import FitSettings
from vpr_edge.features import make_front_end
from vpr_edge.frames.images import list_images, load_image
from vpr_edge.map import build_map, map_from_local
from vpr_edge.map.build import extract_all


@pytest.mark.parametrize("storage", STORAGES)
def test_writer_in_any_order_equals_packing_all(storage: str) -> None:
    rng = np.random.default_rng(0)
    x = rng.normal(size=(23, 40)).astype(np.float32)
    w = EncodingWriter(23, 40, storage)
    order = rng.permutation(23)
    for i in range(0, 23, 5):
        w.put(order[i:i + 5], x[order[i:i + 5]])
    whole = Encodings.pack(x, storage)
    got = w.encodings()
    np.testing.assert_array_equal(got.values, whole.values)
    if storage == "int8":
        np.testing.assert_array_equal(got.scale, whole.scale)
    part = EncodingWriter(3, 40, storage)
    part.put(np.array([0, 2]), x[:2])
    with pytest.raises(ValueError, match="1 references were never encoded"):
        part.encodings()


def test_concat_copies_stored_rows() -> None:
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(7, 30)), rng.normal(size=(4, 30))
    ea = Encodings.pack(a, "int8")
    both = ea.concat(Encodings.pack(b, "float32"))        # the second repacked into the first's storage
    assert both.storage == "int8" and both.shape == (11, 30)
    np.testing.assert_array_equal(both.values[:7], ea.values)
    np.testing.assert_array_equal(both.values[7:], Encodings.pack(b, "int8").values)
    np.testing.assert_array_equal(both.scale, np.concatenate([ea.scale, Encodings.pack(b, "int8").scale]))


@pytest.fixture(scope="module")
def pixels_local(small_refs: Path, tmp_path_factory: pytest.TempPathFactory) -> np.ndarray:
    front = make_front_end("pixels")
    local, _ = extract_all(list_images(small_refs), front, tmp_path_factory.mktemp("local"))
    return np.array(local)


def test_small_route_fits_on_every_reference(small_refs: Path, pixels_local: np.ndarray) -> None:
    """Fewer descriptors than the pool: build_map fits and encodes as map_from_local on all of them."""
    files = list_images(small_refs)
    front = make_front_end("pixels")
    s = FitSettings(n_components=4, max_descriptors=10_000, iterations=10)
    built = build_map(files, front, "ifv", settings=s, storage="float32")
    whole = map_from_local(pixels_local, None, front, [f.name for f in files], str(small_refs), "ifv", settings=s)
    np.testing.assert_allclose(built.encoder.gmm.means, whole.encoder.gmm.means, rtol=1e-6)
    np.testing.assert_allclose(built.encodings, whole.encodings, atol=1e-6)
    assert built.meta["codebook"] == whole.meta["codebook"]


def test_long_route_fits_on_a_pool_and_describes_each_image_once(
        small_refs: Path, pixels_local: np.ndarray, monkeypatch: pytest.MonkeyPatch) -> None:
    files = list_images(small_refs)
    loads: list[str] = []

    def counted(path: Path) -> np.ndarray:
        loads.append(Path(path).name)
        return load_image(path)

    monkeypatch.setattr(mapfile, "load_image", counted)
    front = make_front_end("pixels")        # 32 descriptors an image
    s = FitSettings(n_components=4, max_descriptors=40, iterations=10, seed=3)
    built = build_map(files, front, "ifv", settings=s, batch_size=4, storage="int8")
    assert sorted(loads) == [f.name for f in files]           # every image read once
    assert built.meta["codebook"]["descriptors"] == 40
    # every reference encoded with the fitted codebook from its own descriptors, stored packed
    expected = Encodings.pack(built.encoder.transform(pixels_local), "int8")
    assert built.stored.storage == "int8"
    assert np.abs(built.stored.values.astype(int) - expected.values.astype(int)).max() <= 1
    np.testing.assert_allclose(built.stored.dense(), expected.dense(), atol=2e-3)
    # the pool: whole images drawn at random in batches of 4 until FIT_POOL x 40 = 160 descriptors (5 images)
    # are held, so 8 images, read first; the other 16 after
    assert mapfile.FIT_POOL == 4
    order = np.random.default_rng(3).permutation(len(files))
    assert sorted(loads[:8]) == sorted(files[i].name for i in order[:8])


@pytest.mark.slow
def test_library_defaults_are_the_commands(tmp_path: Path, small_refs: Path) -> None:
    """``build_map`` with no options makes the map ``vpr-edge build-map`` makes (one owner per default: the PCA
    to 24 dims, 41 components, IFV, int8 storage): the same codebook and the same stored encodings."""
    from typer.testing import CliRunner

    from vpr_edge.cli import app
    from vpr_edge.map import load_map, map_front_end

    out = tmp_path / "cli.map.npz"
    assert CliRunner().invoke(app, ["build-map", str(small_refs), "-o", str(out)]).exit_code == 0
    cli = load_map(out)
    lib = build_map(list_images(small_refs), map_front_end(cli, out))
    assert lib.stored.storage == cli.stored.storage == "int8"
    assert lib.encoder.name == cli.encoder.name == "ifv" and lib.encoder.pca is not None
    np.testing.assert_array_equal(lib.stored.values, cli.stored.values)
    np.testing.assert_array_equal(lib.stored.scale, cli.stored.scale)
