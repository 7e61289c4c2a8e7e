"""Property-based tests (hypothesis, fixed seed, bounded examples): damaged or hostile maps, model metadata,
ground-truth and similarity files either load into something valid or are refused with a VprError (one line,
exit 2 at the CLI) — never another exception, never a hang, never a change to the file."""
from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from vpr_edge.cli import app
from vpr_edge.errors import VprError
from vpr_edge.evaluation import sources, truth
from vpr_edge.features.cnn import _checked_info
from vpr_edge.features.patches import Patches
from vpr_edge.files.npz import read_npz, write_npz
from vpr_edge.map import MAP_SCHEMA, load_map, map_from_local, save_map

FUZZ = settings(max_examples=200, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-2**40, 2**40) | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=4),
    max_leaves=8)


@pytest.fixture(scope="module")
def valid_map(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, dict]:
    """A small valid map (SeqSLAM patches, no encoding: no model, nothing to fit) as (arrays, metadata)."""
    rng = np.random.default_rng(0)
    front = Patches()
    local, _ = front.local([rng.integers(0, 255, (32, 64, 3), dtype=np.uint8) for _ in range(6)])
    pm = map_from_local(local, None, front, [f"{i}.png" for i in range(6)], "refs", "none")
    path = tmp_path_factory.mktemp("fuzz") / "valid.npz"
    save_map(pm, path)
    arrays, meta = read_npz(path, "map", MAP_SCHEMA)
    return {k: np.array(v) for k, v in arrays.items()}, meta


def _load_and_use(path: Path) -> None:
    """What localize does with a map once loaded: a similarity row for a query encoding."""
    pm = load_map(path, mmap=True)
    q = np.random.default_rng(1).normal(size=(1, pm.stored.shape[1])).astype(np.float32)
    sim = pm.similarity(q / np.linalg.norm(q))
    assert sim.shape == (1, len(pm.names)) and np.isfinite(sim).all()


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@FUZZ
@given(edits=st.dictionaries(st.sampled_from(["names", "storage", "schema", "features", "encoding",
                                              "descriptor_dim", "n_refs", "dim", "svm", "alpha", "appended", "drives",
                                              "model", "codebook", "kind", "other"]), json_values, min_size=1,
                             max_size=3))
def test_map_metadata_mutations(valid_map: tuple[dict, dict], tmp_path: Path, edits: dict) -> None:
    arrays, meta = valid_map
    path = tmp_path / "m.npz"
    write_npz(path, arrays, meta | edits)
    before = _digest(path)
    try:
        _load_and_use(path)
    except VprError as e:
        assert str(path) in str(e) and "\n" not in str(e)
    res = CliRunner().invoke(app, ["info", str(path)])
    # the map is read (0) or refused in one line naming it (2); any other exit or an exception is a bug
    assert res.exit_code in (0, 2), (res.exit_code, res.exception, res.stderr)
    assert res.exception is None or type(res.exception) is SystemExit and res.exception.code == 2, res.exception
    if res.exit_code == 2:
        assert res.stderr.count("\n") == 1 and res.stderr.startswith(f"vpr-edge: error: {path}"), res.stderr
    assert _digest(path) == before


@FUZZ
@given(name=st.sampled_from(["encodings", "encodings_scale", "encoder_x", "svm_bias"]),
       dtype=st.sampled_from(["int8", "float16", "float32", "float64", "int64", "bool", "uint8"]),
       shape=st.lists(st.integers(0, 7), min_size=0, max_size=3), fill=st.sampled_from([0.0, 1.0, np.nan, np.inf]))
def test_map_array_mutations(valid_map: tuple[dict, dict], tmp_path: Path, name: str, dtype: str, shape: list,
                             fill: float) -> None:
    arrays, meta = valid_map
    value = np.full(shape, fill if np.issubdtype(np.dtype(dtype), np.floating) else 1, dtype=dtype)
    path = tmp_path / "m.npz"
    write_npz(path, arrays | {name: value}, meta)
    try:
        _load_and_use(path)
    except VprError as e:
        assert "\n" not in str(e)


@FUZZ
@given(cuts=st.lists(st.tuples(st.floats(0, 1), st.integers(0, 255)), min_size=1, max_size=6))
def test_map_byte_damage(valid_map: tuple[dict, dict], tmp_path: Path, cuts: list) -> None:
    arrays, meta = valid_map
    path = tmp_path / "m.npz"
    write_npz(path, arrays, meta)
    data = bytearray(path.read_bytes())
    for where, byte in cuts:
        data[min(int(where * len(data)), len(data) - 1)] = byte
    path.write_bytes(bytes(data))
    try:
        _load_and_use(path)
    except VprError as e:
        assert "\n" not in str(e)


MODEL_INFO = {"schema": 1, "backbone": "efficientnet_lite0", "tap": "stage5", "input_width": 320,
              "input_height": 240, "mean": [0.5, 0.5, 0.5], "std": [0.5, 0.5, 0.5], "channels": 112,
              "grid_width": 20, "grid_height": 15, "weights_sha256": "ab"}


@FUZZ
@given(edits=st.dictionaries(st.sampled_from(sorted(MODEL_INFO) + ["resize"]), json_values, min_size=1,
                             max_size=3), drop=st.booleans())
def test_model_metadata_mutations(edits: dict, drop: bool) -> None:
    info = {k: v for k, v in (MODEL_INFO | edits).items() if not (drop and k in edits)}
    try:
        checked = _checked_info(Path("model.onnx"), json.dumps(info))
    except VprError as e:
        assert str(e).startswith("model.onnx: ") and "\n" not in str(e)
        return
    for key in ("input_width", "input_height", "channels", "grid_width", "grid_height"):
        assert isinstance(checked[key], int) and checked[key] > 0
    assert all(math.isfinite(v) for v in checked["mean"] + checked["std"]) and min(checked["std"]) > 0


@st.composite
def spreadsheet_csv(draw: st.DrawFn) -> bytes:
    """A ground-truth CSV as a spreadsheet may save it: a byte-order mark or not, CRLF or LF, blank lines and
    rows of empty cells, quoted cells, duplicated and out-of-order rows, stray text."""
    cell = st.one_of(st.integers(-2, 30).map(str), st.text(alphabet=" 0123456789x\"", max_size=6),
                     st.just(""), st.lists(st.integers(0, 30), max_size=3).map(lambda v: " ".join(map(str, v))))
    rows = draw(st.lists(st.tuples(cell, cell).map(lambda r: f'"{r[0]}",{r[1]}' if draw(st.booleans()) else
                                                   f"{r[0]},{r[1]}") | st.sampled_from(["", ",", ",,"]),
                         max_size=8))
    end = draw(st.sampled_from(["\n", "\r\n"]))
    text = end.join([draw(st.sampled_from(["query,references", "Query,References", "query;references"]))] + rows)
    return (b"\xef\xbb\xbf" if draw(st.booleans()) else b"") + text.encode()


@FUZZ
@given(data=st.one_of(st.binary(max_size=120), st.text(max_size=80).map(lambda t: t.encode("utf-8", "surrogatepass")),
                      spreadsheet_csv()))
def test_csv_readers_take_any_bytes(tmp_path: Path, data: bytes) -> None:
    """Every CSV reader (ground truth, positions, timestamps) and the descriptor readers (.npy, .h5), through
    the same functions the CLI calls, on any bytes, any Unicode text and spreadsheet-style files: a valid
    result or one VprError line naming the file, never another exception."""
    from vpr_edge.frames.images import read_stamps
    from vpr_edge.positions.csv import read_csv as read_positions

    path = tmp_path / "f.csv"
    path.write_bytes(data)
    for read in (truth.load_csv, lambda p: read_positions(p, None), lambda p: read_stamps(p, ["a.png"])):
        try:
            read(path)
        except VprError as e:
            assert str(path) in str(e) and "\n" not in str(e)
    from vpr_edge.frames.descriptor_files import read_descriptors

    for name in ("d.npy", "d.h5"):   # the same bytes as a descriptor file
        (tmp_path / name).write_bytes(data)
        try:
            values, names = read_descriptors(tmp_path / name)
            assert values.ndim == 2 and len(names) == len(values)
        except VprError as e:
            assert name in str(e) and "\n" not in str(e)


IMAGE_HEADS = [b"\xff\xd8", b"\xff\xd8\xff\xe1\x00\x40Exif\x00\x00II*\x00\x08\x00\x00\x00",
               b"\x89PNG\r\n\x1a\n\x00\x00\x00\x0dIHDR", b"BM", b"II*\x00", b"MM\x00*", b"RIFF\x00\x00\x00\x00WEBPVP8X",
               b"RIFF\x00\x00\x00\x00WEBPVP8 ", b"P6\n", b""]


@FUZZ
@given(head=st.sampled_from(IMAGE_HEADS), tail=st.binary(max_size=200))
def test_image_headers_take_any_bytes(tmp_path: Path, head: bytes, tail: bytes) -> None:
    """build-map reads each reference's size from its header (``frames.headers``): whatever follows a
    format's magic bytes, a size of two positive numbers or None (left to the decoder), never an exception."""
    from vpr_edge.frames.headers import image_size

    path = tmp_path / "f.img"
    path.write_bytes(head + tail)
    size = image_size(path)
    assert size is None or (len(size) == 2 and min(size) > 0 and all(isinstance(v, int) for v in size))


@FUZZ
@given(text=st.text(alphabet="0123456789 ,-\nqueryreferencs.x\"", max_size=80))
def test_ground_truth_csv(tmp_path: Path, text: str) -> None:
    path = tmp_path / "gt.csv"
    path.write_text(text)
    try:
        rows = truth.load_csv(path)
    except VprError as e:
        assert str(path) in str(e) and "\n" not in str(e)
        return
    assert rows.ndim == 2 and rows.dtype == np.int64 and (rows >= -1).all()


@FUZZ
@given(dtype=st.sampled_from(["float32", "float64", "int32", "bool", "complex64", "U3", "uint8"]),
       shape=st.lists(st.integers(0, 6), max_size=3), fill=st.sampled_from([0.5, np.nan, -np.inf, 3.0]))
def test_similarity_files(tmp_path: Path, dtype: str, shape: list, fill: float) -> None:
    path = tmp_path / "s.npy"
    kind = np.dtype(dtype).kind
    np.save(path, np.full(shape, fill if kind in "fc" else 1, dtype=dtype), allow_pickle=False)
    try:
        sims = sources.from_file(path)
    except VprError as e:
        assert str(path) in str(e) and "\n" not in str(e)
        return
    assert sims.cosine.ndim == 2 and np.isfinite(sims.cosine).all() and sims.cosine.dtype == np.float64


@pytest.fixture(scope="module")
def valid_codebook(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, dict]:
    """A small valid IFV codebook file (fitted on random descriptors) as (arrays, metadata)."""
    from vpr_edge.encoders import FitSettings, fit_encoder

    local = np.random.default_rng(2).normal(size=(30, 6, 5)).astype(np.float32)
    enc = fit_encoder("ifv", local, None, FitSettings(n_components=3, pca_dim=None), 6)
    path = tmp_path_factory.mktemp("fuzz") / "cb.npz"
    enc.save(path)
    arrays, meta = read_npz(path, "codebook", (1, 2))
    return {k: np.array(v) for k, v in arrays.items()}, meta


@FUZZ
@given(edits=st.dictionaries(st.sampled_from(["encoding", "input_dim", "schema", "features", "kind",
                                              "model_sha256", "features_fingerprint", "other"]), json_values,
                             min_size=1, max_size=3),
       drop=st.sampled_from([None, "means", "variances", "weights", "pca_mean"]))
def test_codebook_mutations(valid_codebook: tuple[dict, dict], tmp_path: Path, edits: dict, drop: str | None) -> None:
    """A codebook file as build-map --codebook reads it (``load_codebook``): metadata mutated, an array
    missing: a codebook that encodes, or one VprError line naming the file."""
    from vpr_edge.encoders import load_codebook

    arrays, meta = valid_codebook
    path = tmp_path / "cb.npz"
    write_npz(path, {k: v for k, v in arrays.items() if not (drop and k.endswith(drop))}, meta | edits)
    try:
        enc, _ = load_codebook(path)
        x = np.random.default_rng(3).normal(size=(2, 6, enc.input_dim)).astype(np.float32)
        out = enc.transform(x)
        assert out.shape == (2, enc.dim) and np.isfinite(out).all()
    except VprError as e:
        assert str(path) in str(e) and "\n" not in str(e)


@FUZZ
@given(dtype=st.sampled_from(["float16", "float32", "float64", "int8", "bool", "complex64", "U3", "O"]),
       shape=st.lists(st.integers(0, 5), max_size=3), fill=st.sampled_from([0.5, np.nan, -np.inf, 3.0]))
def test_descriptor_npy_files(tmp_path: Path, dtype: str, shape: list, fill: float) -> None:
    """Descriptor .npy files of any dtype (objects included, saved with pickle), shape and fill: read as a
    (N, D) float array of finite rows, or one VprError line naming the file; never unpickled."""
    from vpr_edge.frames.descriptor_files import read_descriptors

    path = tmp_path / "d.npy"
    kind = np.dtype(dtype).kind
    np.save(path, np.full(shape, fill if kind in "fc" else 1, dtype=dtype), allow_pickle=kind == "O")
    try:
        values, names = read_descriptors(path)
    except VprError as e:
        assert str(path) in str(e) and "\n" not in str(e)
        return
    assert values.ndim == 2 and values.dtype.kind == "f" and np.isfinite(values).all() and len(names) == len(values)


@pytest.mark.parametrize("bit", [0x1, 0x20, 0x40])   # encrypted, compressed patched data, strong encryption
def test_map_whose_archive_flags_read_as_unsupported_is_one_line(valid_map: tuple[dict, dict], tmp_path: Path,
                                                                  bit: int) -> None:
    arrays, meta = valid_map
    path = tmp_path / "m.npz"
    write_npz(path, arrays, meta)
    data = bytearray(path.read_bytes())
    for sig, at in ((b"PK\x03\x04", 6), (b"PK\x01\x02", 8)):   # each member's local and central flag bits
        i = data.find(sig)
        while i >= 0:
            data[i + at] |= bit
            i = data.find(sig, i + 4)
    path.write_bytes(bytes(data))
    with pytest.raises(VprError) as e:
        _load_and_use(path)
    assert str(e.value).startswith(f"{path}: ") and "\n" not in str(e.value)
