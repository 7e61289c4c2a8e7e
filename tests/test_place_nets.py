"""Place recognition networks in the exporter: random checkpoints saved in each published layout load, export
to ONNX and match torch; the aggregators against naive loops; checkpoints that do not fit are one line."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from vpr_edge.features.cnn import FeatureExtractor  # noqa: E402
from vpr_edge_export.onnx_export import export_global, main as export_main  # noqa: E402
from vpr_edge_export.place_nets import (MixVPR, MixVPRNet, NetVLAD, NetVLADNet, GeoLocalizationNet,  # noqa: E402
                                        build_place_net, resnet_parts, vgg16_conv5_3)

# keys of each published layout (the repositories' own module names), which a checkpoint saved there holds
PUBLISHED = {
    "netvlad": ["encoder.0.weight", "encoder.28.bias", "pool.conv.weight", "pool.centroids"],
    "cosplace": ["backbone.0.weight", "backbone.1.running_var", "backbone.4.0.conv1.weight",
                 "backbone.7.1.bn2.weight", "aggregation.1.p", "aggregation.3.weight", "aggregation.3.bias"],
    "mixvpr": ["backbone.model.conv1.weight", "backbone.model.layer3.5.conv3.weight", "aggregator.mix.0.mix.0.weight",
               "aggregator.mix.1.mix.3.bias", "aggregator.channel_proj.weight", "aggregator.row_proj.bias"],
}


def _randomised(model: torch.nn.Module, seed: int = 0) -> dict[str, torch.Tensor]:
    """The model's state dict with random weights a trained network could have (positive BN variances, GeM p 3)."""
    g = torch.Generator().manual_seed(seed)
    out = {}
    for k, v in model.state_dict().items():
        if not v.dtype.is_floating_point:
            out[k] = v
        elif k.endswith(("running_var", ".p")) or (k.endswith("weight") and v.ndim == 1):
            out[k] = 3.0 * torch.ones_like(v) if k.endswith(".p") else 0.5 + torch.rand(v.shape, generator=g)
        else:
            out[k] = torch.randn(v.shape, generator=g) * (0.5 / max(1, v[0].numel()) ** 0.5)
    return out


NETS = {   # architecture -> (network in its published layout, input width, height)
    "netvlad": (lambda: NetVLADNet(8, False), 64, 48),
    "cosplace": (lambda: GeoLocalizationNet(torch.nn.Sequential(*[m for _, m in resnet_parts("resnet18", 4)]),
                                            512, 32), 64, 48),
    "eigenplaces": (lambda: GeoLocalizationNet(torch.nn.Sequential(*[m for _, m in resnet_parts("resnet50", 4)]),
                                               2048, 64), 64, 48),
    "mixvpr": (lambda: MixVPRNet("resnet50", 3, MixVPR(1024, 16, 64, 2, 1.0, 2)), 64, 64),
}


@pytest.mark.slow
@pytest.mark.parametrize("architecture", list(NETS))
def test_random_checkpoint_exports_and_matches_torch(tmp_path: Path, architecture: str) -> None:
    make, w, h = NETS[architecture]
    reference = make().eval()
    state = _randomised(reference)
    reference.load_state_dict(state)
    for key in PUBLISHED.get(architecture, PUBLISHED["cosplace"]):
        assert key in state, key
    ckpt = tmp_path / "model.pth"
    torch.save({"epoch": 1, "state_dict": {f"module.{k}": v for k, v in state.items()}}, ckpt)   # DataParallel
    model, meta = export_global(architecture, ckpt, w, h, tmp_path / "m.onnx")
    x = torch.randn(3, 3, h, w, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        want = reference(x).numpy()
    ex = FeatureExtractor(tmp_path / "m.onnx")
    got = ex.feature_maps(x.numpy())
    assert ex.is_global and ex.dim == want.shape[1] == meta["channels"]
    assert np.abs(got - want).max() < 1e-4
    assert np.allclose(np.linalg.norm(got, axis=1), 1.0, atol=1e-4)


def test_netvlad_against_a_naive_loop() -> None:
    torch.manual_seed(0)
    layer = NetVLAD(5, 7).eval()
    x = torch.randn(2, 7, 3, 4)
    with torch.no_grad():
        got = layer(x).numpy()
    w, c = layer.conv.weight.detach().numpy()[:, :, 0, 0], layer.centroids.detach().numpy()
    for b in range(2):
        cells = x[b].numpy().reshape(7, -1).T                      # (N, D)
        cells = cells / np.linalg.norm(cells, axis=1, keepdims=True)
        v = np.zeros((5, 7))
        for d in cells:
            logits = w @ d
            a = np.exp(logits - logits.max())
            a /= a.sum()
            for k in range(5):
                v[k] += a[k] * (d - c[k])
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        v = v.ravel() / np.linalg.norm(v)
        assert np.abs(got[b] - v).max() < 1e-5


def test_mixvpr_against_a_naive_loop() -> None:
    torch.manual_seed(0)
    agg = MixVPR(in_channels=6, cells=4, out_channels=3, depth=2, ratio=2.0, out_rows=2).eval()
    x = torch.randn(1, 6, 2, 2)
    with torch.no_grad():
        got = agg(x).numpy()[0]
    p = {k: v.numpy() for k, v in agg.state_dict().items()}
    feats = x[0].numpy().reshape(6, 4)
    for layer in range(2):
        out = np.empty_like(feats)
        for ch in range(6):
            r = feats[ch]
            n = (r - r.mean()) / np.sqrt(r.var() + 1e-5) * p[f"mix.{layer}.mix.0.weight"] + p[f"mix.{layer}.mix.0.bias"]
            hdn = np.maximum(p[f"mix.{layer}.mix.1.weight"] @ n + p[f"mix.{layer}.mix.1.bias"], 0)
            out[ch] = r + p[f"mix.{layer}.mix.3.weight"] @ hdn + p[f"mix.{layer}.mix.3.bias"]
        feats = out
    chan = p["channel_proj.weight"] @ feats + p["channel_proj.bias"][:, None]        # (3, cells)
    rows = chan @ p["row_proj.weight"].T + p["row_proj.bias"]                        # (3, 2)
    want = rows.ravel() / np.linalg.norm(rows)
    assert np.abs(got - want).max() < 1e-5


def test_checkpoint_that_does_not_fit_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    net = GeoLocalizationNet(vgg16_conv5_3(), 512, 16)
    state = {k: v.clone() for k, v in net.state_dict().items()}
    del state["backbone.26.weight"]
    state["aggregation.3.bias"] = torch.zeros(17)
    ckpt = tmp_path / "bad.pth"
    torch.save(state, ckpt)
    with pytest.raises(ValueError) as e:
        build_place_net("cosplace", dict(state), (64, 48), str(ckpt))
    msg = str(e.value)
    assert "1 key(s) missing (backbone.26.weight)" in msg and "aggregation.3.bias: (17,) given, (16,) expected" in msg
    out = tmp_path / "m.onnx"
    assert export_main(["--architecture", "cosplace", "--weights", str(ckpt), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("onnx_export: error:") and str(ckpt) in err[0], err
    assert not out.exists()
    # a trained architecture without its checkpoint: no weights are downloaded
    assert export_main(["--architecture", "netvlad", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "give its checkpoint with --weights FILE" in err[0] and not out.exists()
    # a checkpoint of another architecture: what it lacks, named
    assert export_main(["--architecture", "mixvpr", "--weights", str(ckpt), "--out", str(out)]) == 2
    assert "not a mixvpr checkpoint" in capsys.readouterr().err
    # MixVPR's mixers fix the feature map: an input size that does not give it is refused with the size it needs
    mix = MixVPRNet("resnet18", 3, MixVPR(256, 16, 8, 1, 1.0, 1))
    torch.save(mix.state_dict(), tmp_path / "mix.pth")
    assert export_main(["--architecture", "mixvpr", "--weights", str(tmp_path / "mix.pth"), "--width", "320",
                        "--height", "240", "--out", str(out)]) == 2
    assert "16 cells" in capsys.readouterr().err and not out.exists()


@pytest.mark.slow
def test_lite0_gem_global_front_end_quantises_and_localises(tmp_path: Path, small_refs: Path,
                                                           small_queries: Path) -> None:
    """The bundled Lite0's stage5 + GeM (ImageNet weights) as a global model: exported with its metadata
    (no conventions to state), its int8 form made by quantize, a map of 112 dims, localize in either form."""
    from typer.testing import CliRunner

    from vpr_edge.cli import app
    from vpr_edge_export.onnx_export import default_weights
    from vpr_edge_export.quantize import main as quantize_main

    fp32 = tmp_path / "lite0_gem.onnx"
    _, meta = export_global("gem", default_weights("efficientnet_lite0"), 160, 120, fp32, backbone="efficientnet_lite0",
                            tap="stage5")
    assert (meta["output"], meta["channels"], meta["tap"]) == ("global", 112, "stage5+gem")
    assert quantize_main(["--model", str(fp32), "--calibration", str(small_refs), "--images", "8", "--out",
                          str(tmp_path / "lite0_gem.int8.onnx")]) == 0
    runner = CliRunner()
    res = runner.invoke(app, ["build-map", str(small_refs), "-o", str(tmp_path / "m.npz"), "--model", str(fp32)])
    assert res.exit_code == 0 and "112-dim int8 cnn + none" in res.stderr, res.stderr
    answers = {}
    for precision in ("fp32", "int8"):
        out = tmp_path / f"{precision}.csv"
        res = runner.invoke(app, ["localize", "-m", str(tmp_path / "m.npz"), "-s", str(small_queries), "-o", str(out),
                                  "--mode", "single", "--precision", precision])
        assert res.exit_code == 0, res.stderr
        answers[precision] = [int(r.split(",")[3]) for r in out.read_text().splitlines()[1:]]
    hits = [abs(a - i) <= 1 for i, a in enumerate(answers["fp32"])]
    assert np.mean(hits) > 0.5                                   # the aligned sample: mostly its own place
    assert np.mean(np.equal(answers["fp32"], answers["int8"])) > 0.7
