"""Static int8 quantisation of a vpr-edge ONNX tap, calibrated on reference images.

    python -m vpr_edge_export.quantize --model vpr_edge/models/efficientnet_lite0_stage5_320x240.onnx \\
        --calibration corridor/ref --out lite0_int8.onnx

onnxruntime's static quantisation, weights per channel, activation ranges by MinMax over the calibration
images, preprocessed exactly as the runtime does. The default, and the bundled int8 forms, is U8S8 with
reduce_range in the QOperator format: 7-bit weights keep every int8 product sum inside 16 bits, so x86 with
or without VNNI and ARM compute the same integers and give the same answers. U8U8 (``--weights uint8``) does
not: onnxruntime's x86 kernels without VNNI give feature maps far from the VNNI ones (decisions.md, "fp32 by
default, int8 beside it"). Dynamic quantisation is not offered (slower and less accurate here). The
figures: docs/results.md, "The default". The model's ``vpr_edge`` metadata is copied and marked (``quantization``: scheme, calibration images, source
SHA-256), so maps record which model they were built with and refuse the other one; a codebook fitted with
the source model is accepted. Written atomically. Needs the ``export`` extra (onnx).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from vpr_edge.errors import VprError, one_line_errors
from vpr_edge.features.cnn import FeatureExtractor
from vpr_edge.frames.images import list_images, load_image
from vpr_edge.files.atomic import atomic_output
from vpr_edge.files.checks import check_writable
from vpr_edge.files.readers import file_sha256


class _Images:
    """onnxruntime CalibrationDataReader over preprocessed images, one per call."""

    def __init__(self, extractor: FeatureExtractor, files: list[Path]) -> None:
        self._feeds = iter([{extractor.session.get_inputs()[0].name: extractor.preprocess(load_image(f))[None]}
                            for f in files])

    def get_next(self) -> dict[str, np.ndarray] | None:
        return next(self._feeds, None)


def calibration_files(folder: Path, count: int) -> list[Path]:
    """``count`` images spread evenly over the folder's name order (all of them if fewer)."""
    files = list_images(folder)
    idx = np.unique(np.linspace(0, len(files) - 1, min(count, len(files))).round().astype(int))
    return [files[i] for i in idx]


FORMATS = {"qdq": "QDQ", "qoperator": "QOperator"}


def quantize(model: Path, calibration: Path, out: Path, count: int = 32, weights: str = "int8",
             fmt: str = "qoperator") -> dict:
    """Write the int8 model of ``model`` to ``out``, calibrated on ``count`` images of ``calibration``;
    return its metadata. ``weights``: int8 (U8S8 with reduce_range: the same answers on every CPU) or uint8
    (U8U8: far off on x86 without VNNI). ``fmt``: qdq (QuantizeLinear /
    DequantizeLinear pairs around float operators, fused by onnxruntime at load) or qoperator (QLinearConv
    and friends written into the graph)."""
    if fmt not in FORMATS:
        raise ValueError(f"unknown format {fmt!r}; choose from {', '.join(FORMATS)}")
    import onnx
    from onnxruntime.quantization import CalibrationMethod, QuantFormat, QuantType, quantize_static
    from onnxruntime.quantization.shape_inference import quant_pre_process

    extractor = FeatureExtractor(model)
    files = calibration_files(calibration, count)
    meta = dict(extractor.info) | {"quantization": {
        "scheme": f"static {FORMATS[fmt]}, {'U8U8' if weights == 'uint8' else 'U8S8 reduce_range'}, "
                  f"weights per channel, activations MinMax",
        "calibration_images": len(files), "calibration_folder": str(calibration),
        "source_model": model.name, "source_sha256": extractor.fingerprint}}
    with tempfile.TemporaryDirectory(dir=out.parent) as tmp:
        prepared, raw = Path(tmp) / "prepared.onnx", Path(tmp) / "int8.onnx"
        quant_pre_process(str(model), str(prepared))
        quantize_static(str(prepared), str(raw), _Images(extractor, files),
                        quant_format=getattr(QuantFormat, FORMATS[fmt]), per_channel=True,
                        activation_type=QuantType.QUInt8,
                        weight_type=QuantType.QUInt8 if weights == "uint8" else QuantType.QInt8,
                        reduce_range=weights == "int8", calibrate_method=CalibrationMethod.MinMax)
        proto = onnx.load(str(raw))
        del proto.metadata_props[:]
        entry = proto.metadata_props.add()
        entry.key, entry.value = "vpr_edge", json.dumps(meta, sort_keys=True)
        with atomic_output(out) as final:
            onnx.save(proto, str(final))
    return meta


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point: quantise, then print the metadata and the cosine to the fp32 features."""
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--model", type=Path, required=True, help="fp32 model exported by vpr_edge_export.onnx_export")
    p.add_argument("--calibration", type=Path, required=True, help="folder of reference images")
    p.add_argument("--images", type=int, default=32, help="calibration images, spread over the folder")
    p.add_argument("--weights", choices=("int8", "uint8"), default="int8",
                   help="int8: U8S8 with reduce_range, the same answers on every CPU (default); uint8: U8U8, "
                        "far off on x86 without VNNI")
    p.add_argument("--format", choices=tuple(FORMATS), default="qoperator",
                   help="qoperator: QLinearConv etc. in the graph (default, the fastest here); qdq: Q/DQ pairs "
                        "fused by onnxruntime")
    p.add_argument("--out", type=Path, required=True)
    a = p.parse_args(argv)
    return one_line_errors("quantize", lambda: _run(a))


def _run(a: argparse.Namespace) -> int:
    """The work of ``main``, inputs checked first: the model opens, the folder holds images, ``--out`` can be
    written and is not the model."""
    FeatureExtractor(a.model)
    calibration_files(a.calibration, 1)
    if a.images < 1:
        raise VprError(f"--images must be at least 1, got {a.images}")
    check_writable(a.out)
    if a.out.resolve() == a.model.resolve():
        raise VprError(f"{a.out}: is the input model; choose another --out")
    meta = quantize(a.model, a.calibration, a.out, a.images, a.weights, a.format)
    print(json.dumps(meta["quantization"], indent=1, sort_keys=True))
    fp32, int8 = FeatureExtractor(a.model), FeatureExtractor(a.out)
    probe = np.stack([fp32.preprocess(load_image(f)) for f in calibration_files(a.calibration, 8)])
    x, y = (m.feature_maps(probe).reshape(len(probe), -1) for m in (fp32, int8))
    cos = (x * y).sum(1) / (np.linalg.norm(x, axis=1) * np.linalg.norm(y, axis=1))
    print(f"wrote {a.out} ({os.path.getsize(a.out) / 1e6:.1f} MB, sha256 {file_sha256(a.out)[:12]}); "
          f"cosine of int8 to fp32 feature maps on 8 calibration images: min {cos.min():.4f}, mean {cos.mean():.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
