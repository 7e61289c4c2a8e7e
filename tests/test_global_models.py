"""A network exported elsewhere whose output is one global descriptor an image: its input conventions stated
on the command line, recorded in the map, and the encodings it gives against a naive NumPy computation.

The models are written with ``onnx.helper`` (the export extra): a 4x4 grid of mean colours (48 dims) in
NCHW or NHWC, with a dynamic or a fixed batch size; a model whose output has rank 3; one that gives NaN
for dark images; one that needs an operator onnxruntime's CPU provider lacks.
"""
from __future__ import annotations

import hashlib
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

onnx = pytest.importorskip("onnx")
from onnx import TensorProto, helper  # noqa: E402

from vpr_edge import Localizer  # noqa: E402
from vpr_edge.cli import app  # noqa: E402
from vpr_edge.evaluation.truth import write_ground_truth  # noqa: E402
from vpr_edge.frames.images import list_images, load_image  # noqa: E402
from vpr_edge.map import load_map  # noqa: E402
from vpr_edge.map.query import MapQuery  # noqa: E402

W, H, GRID = 64, 48, 4
MEAN, STD = (0.485, 0.456, 0.406), (0.229, 0.224, 0.225)
CONVENTIONS = ["--mean", "imagenet", "--std", "imagenet"]


def _write(path: Path, nodes: list, inp: list, out: list, init: list | None = None) -> Path:
    graph = helper.make_graph(nodes, "g", [helper.make_tensor_value_info("image", TensorProto.FLOAT, inp)],
                              [helper.make_tensor_value_info("descriptor", TensorProto.FLOAT, out)], init or [])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.save(model, str(path))
    return path


def grid_model(path: Path, layout: str = "nchw", batch: int | str = "batch", out_rank: int = 2,
               nan_when_dark: bool = False) -> Path:
    """Mean colour of each cell of a 4x4 grid, flattened (batch, 48) (rank 3: (batch, 1, 48))."""
    nodes, x = [], "image"
    if layout == "nhwc":
        nodes.append(helper.make_node("Transpose", ["image"], ["x"], perm=[0, 3, 1, 2]))
        x = "x"
    nodes.append(helper.make_node("AveragePool", [x], ["pooled"], kernel_shape=[H // GRID, W // GRID],
                                  strides=[H // GRID, W // GRID]))
    nodes.append(helper.make_node("Flatten", ["pooled"], ["flat"], axis=1))
    init = []
    last = "flat"
    if nan_when_dark:   # sqrt(mean + 1.5): NaN where the normalised image is very dark
        init.append(helper.make_tensor("shift", TensorProto.FLOAT, [1], [1.5]))
        nodes += [helper.make_node("ReduceMean", ["flat"], ["m"], axes=[1], keepdims=1),
                  helper.make_node("Add", ["m", "shift"], ["m2"]), helper.make_node("Sqrt", ["m2"], ["s"]),
                  helper.make_node("Mul", ["flat", "s"], ["scaled"])]
        last = "scaled"
    if out_rank == 3:
        init.append(helper.make_tensor("axes", TensorProto.INT64, [1], [1]))
        nodes.append(helper.make_node("Unsqueeze", [last, "axes"], ["descriptor"]))
        out = [batch, 1, 3 * GRID * GRID]
    else:
        nodes.append(helper.make_node("Identity", [last], ["descriptor"]))
        out = [batch, 3 * GRID * GRID]
    inp = [batch, 3, H, W] if layout == "nchw" else [batch, H, W, 3]
    return _write(path, nodes, inp, out, init)


def naive(images: list[np.ndarray], bgr: bool = False) -> np.ndarray:
    """The grid model's L2-normalised descriptors by hand: stretch to W x H, (x/255 - mean)/std, cell means."""
    out = []
    for rgb in images:
        interp = cv2.INTER_AREA if rgb.shape[1] > W else cv2.INTER_LINEAR
        x = cv2.resize(rgb, (W, H), interpolation=interp).astype(np.float64) / 255.0
        if bgr:
            x = x[:, :, ::-1]
        x = (x - np.array(MEAN)) / np.array(STD)
        cells = x.reshape(GRID, H // GRID, GRID, W // GRID, 3).mean(axis=(1, 3))   # (gy, gx, c)
        v = cells.transpose(2, 0, 1).ravel()
        out.append(v / np.linalg.norm(v))
    return np.array(out)


@pytest.fixture(scope="module")
def models(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("global")
    return {"nchw": grid_model(d / "nchw.onnx"), "nhwc1": grid_model(d / "nhwc1.onnx", "nhwc", 1),
            "nchw4": grid_model(d / "nchw4.onnx", batch=4), "rank3": grid_model(d / "rank3.onnx", out_rank=3),
            "nan": grid_model(d / "nan.onnx", nan_when_dark=True)}


def _build(refs: Path, out: Path, model: Path, *extra: str) -> None:
    res = CliRunner().invoke(app, ["build-map", str(refs), "-o", str(out), "--model", str(model), *CONVENTIONS,
                                   *extra])
    assert res.exit_code == 0, res.stderr
    assert "cnn + none encodings" in res.stderr


def test_global_model_map_is_its_descriptors(tmp_path: Path, small_refs: Path, models: dict[str, Path]) -> None:
    """The map holds each reference's descriptor as the naive computation gives it, about D bytes a place,
    and records the stated conventions; NCHW with a dynamic batch, NHWC with a batch fixed at 1 and NCHW fixed
    at 4 (run on batches of 3: the last run padded) give the same encodings."""
    files = list_images(small_refs)
    want = naive([load_image(f) for f in files])
    maps = {}
    for key, extra in (("nchw", []), ("nhwc1", []), ("nchw4", ["--batch-size", "3"])):
        _build(small_refs, tmp_path / f"{key}.npz", models[key], *extra)
        maps[key] = load_map(tmp_path / f"{key}.npz")
        got = maps[key].encodings
        assert np.abs(got - want).max() < 0.02, key      # int8 storage
    pm = maps["nchw"]
    assert pm.stored.bytes_per_place <= 48 + 8
    assert pm.features["params"]["input"] == {"input_width": W, "input_height": H, "mean": list(MEAN),
                                              "std": list(STD), "bgr": False, "layout": "nchw"}
    assert maps["nhwc1"].features["params"]["input"]["layout"] == "nhwc"     # read from the input shape
    q = MapQuery(tmp_path / "nchw.npz")
    assert np.abs(q.encode([load_image(f) for f in files[:5]]) - want[:5]).max() < 1e-5   # queries: float32


def test_bgr_model_reads_channels_reversed(tmp_path: Path, small_refs: Path, models: dict[str, Path]) -> None:
    files = list_images(small_refs)[:6]
    _build(small_refs, tmp_path / "bgr.npz", models["nchw"], "--bgr")
    q = MapQuery(tmp_path / "bgr.npz")
    assert np.abs(q.encode([load_image(f) for f in files]) - naive([load_image(f) for f in files], bgr=True)).max() < 1e-5


def test_global_model_localize_evaluate_and_localizer_agree(tmp_path: Path, small_refs: Path, small_queries: Path,
                                                              models: dict[str, Path]) -> None:
    """localize answers with the map's recorded conventions (no options at run time); Localizer gives the
    same answers; evaluate runs."""
    _build(small_refs, tmp_path / "m.npz", models["nchw"])
    runner = CliRunner()
    res = runner.invoke(app, ["localize", "-m", str(tmp_path / "m.npz"), "-s", str(small_queries), "-o",
                              str(tmp_path / "out.csv"), "--mode", "single"])
    assert res.exit_code == 0, res.stderr
    rows = (tmp_path / "out.csv").read_text().splitlines()[1:]
    assert len(rows) == len(list_images(small_queries))
    loc = Localizer(tmp_path / "m.npz", mode="single")
    for line, f in zip(rows, list_images(small_queries)):
        assert int(line.split(",")[3]) == loc.push(load_image(f)).ref_index
    write_ground_truth(tmp_path / "gt.csv", [[i] for i in range(len(rows))])   # the sample is aligned
    res = runner.invoke(app, ["evaluate", "--map", str(tmp_path / "m.npz"), "--queries", str(small_queries),
                              "--gt", str(tmp_path / "gt.csv"), "--modes", "single,stream", "--json",
                              str(tmp_path / "e.json")])
    assert res.exit_code == 0, res.stderr


def _refused(tmp_path: Path, args: list[str], *needles: str, first: str = "vpr-edge: error: ") -> None:
    """The command exits 2 with one error line that starts with ``first`` and holds every needle; nothing
    written."""
    before = sorted(p.name for p in tmp_path.iterdir())
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 2, res.stderr
    lines = [ln for ln in res.stderr.splitlines() if ln.startswith("vpr-edge: error:")]
    assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr
    assert lines[0].startswith(first), (first, lines[0])
    for n in needles:
        assert n in lines[0], lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == before


@pytest.mark.parametrize("extra, named, needles", [
    ([], "model", ["no vpr_edge metadata", "--mean"]),                                    # conventions unknown
    (["--mean", "0.5,0.5", "--std", "imagenet"], "option", ["--mean", "three numbers"]),   # wrong length
    (["--mean", "imagenet", "--std", "0,1,1"], "option", ["--std", "positive"]),
    (["--mean", "imagenet", "--std", "imagenet", "--input-size", "320x240"], "model", ["contradicts", "64x48"]),
    (["--mean", "imagenet", "--std", "imagenet", "--layout", "nhwc"], "model", ["channels, not 3"]),
    (["--mean", "imagenet", "--std", "imagenet", "--input-size", "64by48"], "option", ["WIDTHxHEIGHT"]),
    (["--mean", "imagenet", "--std", "imagenet", "--encoding", "ifv"], "model", ["global-descriptor", "--encoding ifv"]),
])
def test_bad_conventions_refused(tmp_path: Path, small_refs: Path, models: dict[str, Path], extra: list[str],
                                 named: str, needles: list[str]) -> None:
    """Each refusal names what is wrong: the model file where the model and the options disagree, the option
    where its value alone is wrong."""
    model = str(models["nchw"])
    first = f"vpr-edge: error: {model}: " if named == "model" else "vpr-edge: error: --"
    _refused(tmp_path, ["build-map", str(small_refs), "-o", str(tmp_path / "m.npz"), "--model", model, *extra],
             *needles, first=first)


def test_output_of_rank_3_refused(tmp_path: Path, small_refs: Path, models: dict[str, Path]) -> None:
    _refused(tmp_path, ["build-map", str(small_refs), "-o", str(tmp_path / "m.npz"), "--model",
                        str(models["rank3"]), *CONVENTIONS], "rank 3", str(models["rank3"]))


def test_conventions_need_a_model_without_metadata(tmp_path: Path, small_refs: Path, model_path: Path) -> None:
    _refused(tmp_path, ["build-map", str(small_refs), "-o", str(tmp_path / "m.npz"), *CONVENTIONS],
             "--mean", "--model")
    _refused(tmp_path, ["build-map", str(small_refs), "-o", str(tmp_path / "m.npz"), "--model", str(model_path),
                        *CONVENTIONS], "records its input conventions", "drop --mean")


def test_nan_output_refused_naming_the_image(tmp_path: Path, small_refs: Path, models: dict[str, Path]) -> None:
    refs = tmp_path / "refs"
    refs.mkdir()
    for f in list_images(small_refs)[:5]:
        (refs / f.name).write_bytes(f.read_bytes())
    cv2.imwrite(str(refs / "zz_black.png"), np.zeros((48, 64, 3), np.uint8))
    out = tmp_path / "out"
    out.mkdir()
    _refused(out, ["build-map", str(refs), "-o", str(out / "m.npz"), "--model", str(models["nan"]), *CONVENTIONS],
             "zz_black.png", "NaN")


def test_model_needing_a_missing_operator_refused(tmp_path: Path, small_refs: Path) -> None:
    model = tmp_path.parent / f"custom_{hashlib.md5(str(tmp_path).encode()).hexdigest()[:6]}.onnx"
    graph = helper.make_graph([helper.make_node("FancyPool", ["image"], ["descriptor"], domain="com.example")],
                              "g", [helper.make_tensor_value_info("image", TensorProto.FLOAT, ["b", 3, H, W])],
                              [helper.make_tensor_value_info("descriptor", TensorProto.FLOAT, ["b", 8])])
    m = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17), helper.make_opsetid("com.example", 1)])
    m.ir_version = 8
    onnx.save(m, str(model))
    _refused(tmp_path, ["build-map", str(small_refs), "-o", str(tmp_path / "m.npz"), "--model", str(model),
                        *CONVENTIONS], str(model), "not a loadable ONNX model")
