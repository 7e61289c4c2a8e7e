"""Compact storage of map encodings: int8 rows against a plain loop, round trips, old maps still read."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vpr_edge.index.encodings import Encodings, STORAGES, quantise_rows
from vpr_edge.map import MAP_SCHEMA, load_map
from vpr_edge.files.npz import read_npz, write_npz


def naive_quantise(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    q = np.zeros(x.shape, np.int8)
    scale = np.ones(len(x), np.float32)
    for i, row in enumerate(x):
        peak = max(abs(float(v)) for v in row)
        if peak == 0:
            continue
        step = np.float32(peak / 127.0)
        for j, v in enumerate(row):
            q[i, j] = int(min(127, max(-127, round(float(np.float32(v) / step)))))
        scale[i] = np.sqrt(sum(float(v) ** 2 for v in row)) / np.sqrt(sum(float(c) ** 2 for c in q[i]))
    return q, scale


def test_quantise_rows_against_a_plain_loop() -> None:
    rng = np.random.default_rng(0)
    x = rng.normal(size=(6, 40)).astype(np.float32) * rng.uniform(0.01, 3, size=(6, 1)).astype(np.float32)
    x[2] = 0.0
    q, scale = quantise_rows(x)
    nq, nscale = naive_quantise(x)
    assert np.abs(q.astype(int) - nq.astype(int)).max() <= 1      # ties may round either way
    np.testing.assert_allclose(scale, nscale, rtol=1e-3)
    assert scale[2] == 1.0 and not q[2].any()
    back = Encodings.pack(x, "int8").dense()
    np.testing.assert_allclose(np.linalg.norm(back, axis=1), np.linalg.norm(x, axis=1), rtol=1e-5)  # norms kept
    assert np.abs(back - x).max() <= (np.abs(x).max(axis=1) / 127).max()   # within a step per row


@pytest.mark.parametrize("storage", STORAGES)
def test_pack_round_trip_keeps_cosines(storage: str) -> None:
    rng = np.random.default_rng(1)
    x = rng.normal(size=(50, 512)).astype(np.float32)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    q = rng.normal(size=(5, 512)).astype(np.float32)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    enc = Encodings.pack(x, storage)
    back = Encodings.from_arrays(enc.to_arrays(), storage)
    assert back.dense().dtype == np.float32 and back.shape == x.shape
    tol = {"int8": 3e-3, "float16": 2e-4, "float32": 1e-6}[storage]
    np.testing.assert_allclose(back.similarity(q), q @ x.T, atol=tol)
    np.testing.assert_allclose(back.similarity(q), q @ back.dense().T, atol=1e-5)   # blocks == whole
    with pytest.raises(ValueError):
        Encodings.from_arrays(enc.to_arrays(), "int8" if storage != "int8" else "float32")


def test_similarity_in_blocks_from_a_memory_map(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import vpr_edge.index.encodings as encodings

    rng = np.random.default_rng(2)
    x = rng.normal(size=(1000, 64)).astype(np.float32)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    q = rng.normal(size=(3, 64)).astype(np.float32)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    write_npz(tmp_path / "e.npz", Encodings.pack(x, "int8").to_arrays(), {"kind": "enc", "schema": 1})
    arrays, _ = read_npz(tmp_path / "e.npz", "enc", 1, mmap=True)
    assert isinstance(arrays["encodings"], np.memmap)
    monkeypatch.setattr(encodings, "BLOCK_BYTES", 64 * 4 * 7)       # blocks of 7 references: 143 of them
    mapped = Encodings.from_arrays(arrays, "int8")
    np.testing.assert_allclose(mapped.similarity(q), q @ mapped.dense().T, atol=1e-5)
    np.testing.assert_allclose(mapped.similarity(q), q @ x.T, atol=6e-3)      # int8 at 64 dims


@pytest.mark.slow
def test_map_storage_and_schema_1(tmp_path: Path, small_refs: Path) -> None:
    from typer.testing import CliRunner

    from vpr_edge.cli import app

    runner = CliRunner()
    sizes = {}
    for storage in STORAGES:
        out = tmp_path / f"{storage}.npz"
        res = runner.invoke(app, ["build-map", str(small_refs), "-o", str(out), "--components", "4", "--storage",
                                  storage])
        assert res.exit_code == 0, res.stderr
        arrays, _ = read_npz(out, "map", MAP_SCHEMA)
        sizes[storage] = sum(arrays[k].nbytes for k in arrays if k.startswith("encodings"))
    full = load_map(tmp_path / "float32.npz")
    small = load_map(tmp_path / "int8.npz")
    assert small.meta["storage"] == "int8" and small.encodings.dtype == np.float32
    np.testing.assert_allclose(small.encodings, full.encodings, atol=np.abs(full.encodings).max() / 100)
    mapped = load_map(tmp_path / "int8.npz", mmap=True)
    assert isinstance(mapped.stored.values, np.memmap)
    np.testing.assert_array_equal(mapped.encodings, small.encodings)
    assert sizes["int8"] < 0.26 * sizes["float32"] and sizes["float16"] == 0.5 * sizes["float32"]
    # schema-1 and -2 maps (IFV only: codebook_* arrays, alpha at the top level; schema 1: float32, no storage
    # key) written by earlier releases still load, and encode queries as before
    for name, storage in (("float32", None), ("int8", "int8")):
        arrays, meta = read_npz(tmp_path / f"{name}.npz", "map", MAP_SCHEMA)
        arrays = {k.replace("encoder_", "codebook_"): v for k, v in arrays.items()}
        old = {k: v for k, v in meta.items() if k not in ("storage", "features", "encoding", "descriptor_dim")}
        old |= {"schema": 2, "storage": storage} if storage else {"schema": 1}
        write_npz(tmp_path / "old.npz", arrays | {}, old | {"alpha": meta["encoding"]["params"]["alpha"]})
        back, now = load_map(tmp_path / "old.npz"), load_map(tmp_path / f"{name}.npz")
        np.testing.assert_array_equal(back.encodings, now.encodings)
        assert back.encoder.name == "ifv" and back.features["name"] == "cnn"
        x = np.random.default_rng(0).random((2, 5, back.encoder.input_dim)).astype(np.float32)
        np.testing.assert_array_equal(back.encode(x), now.encode(x))


@pytest.mark.parametrize("storage", ["int8", "float16", "float32"])
def test_similarity_of_some_rows(storage: str) -> None:
    rng = np.random.default_rng(5)
    x = rng.normal(size=(50, 16)).astype(np.float32)
    q = rng.normal(size=(2, 16)).astype(np.float32)
    enc = Encodings.pack(x, storage)
    rows = np.array([0, 3, 4, 17, 49])
    np.testing.assert_allclose(enc.similarity(q, rows), enc.similarity(q)[:, rows], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(enc.dense_row(17), enc.dense()[17], rtol=1e-6)
