"""Which model a cnn front end runs: the bundled input size that suits the camera (build-map), and the
model's int8 form where the CPU has int8 dot-product instructions (every command that describes frames).
Measurements behind both policies: docs/decisions.md, "fp32 by default, int8 beside it"."""
from __future__ import annotations

import platform
from functools import lru_cache
from pathlib import Path

from vpr_edge.errors import InputError, VprError
from vpr_edge.resources import MODEL_FILES, bundled_model, int8_form

PRECISIONS = ("fp32", "int8", "auto")
# fp32 by default: it meets the time budget on its own, and the int8 form costs R@1, most on Corridor
# (docs/decisions.md, "fp32 by default, int8 beside it"); auto takes int8 where the CPU has int8 dot products.
DEFAULT_PRECISION = "fp32"


def model_for_frame(width: int, height: int) -> Path:
    """The bundled model for camera frames of ``width`` x ``height`` pixels: the largest input that does not
    exceed the frame on either side (frames are brought down to it, never up), else the smallest input
    (a camera smaller than every model: the least upsampling)."""
    sizes = sorted(MODEL_FILES, key=lambda s: s[0] * s[1])
    fitting = [s for s in sizes if s[0] <= width and s[1] <= height]
    return bundled_model(MODEL_FILES[(fitting or sizes)[-1 if fitting else 0]])


def bundled_for_sha256(sha256: str | None) -> Path | None:
    """The bundled fp32 model whose file has this SHA-256, if any (a map or codebook made on another install)."""
    from vpr_edge.files.readers import file_sha256

    for name in MODEL_FILES.values():
        path = bundled_model(name)
        if sha256 and path.is_file() and file_sha256(path) == sha256:
            return path
    return None


def _cpu_flags() -> set[str]:
    try:
        text = Path("/proc/cpuinfo").read_text(errors="replace")
    except OSError:
        return set()
    flags: set[str] = set()
    for line in text.splitlines():
        key, _, value = line.partition(":")
        if key.strip().lower() in ("flags", "features"):
            flags.update(value.split())
    return flags


@lru_cache(maxsize=1)
def int8_dot_product() -> str | None:
    """The CPU's int8 dot-product instructions, by name, or None: x86 AVX512-VNNI / AVX-VNNI, ARM dotprod
    (Linux's /proc/cpuinfo; elsewhere None, so fp32 is kept). Without them onnxruntime's int8 kernels are
    no faster than fp32, or slower (docs/decisions.md, "fp32 by default, int8 beside it")."""
    flags = _cpu_flags()
    for flag, name in (("avx512_vnni", "AVX512-VNNI"), ("avx_vnni", "AVX-VNNI"), ("asimddp", "ARM dotprod")):
        if flag in flags:
            return name
    return None


def int8_sibling(fp32: Path) -> Path | None:
    """The int8 form kept beside the model ``fp32`` (``resources.int8_form``), if there is one. Whoever runs
    it checks that its metadata names ``fp32`` as its source (``FeatureExtractor.source_fingerprint``)."""
    path = fp32.with_name(int8_form(fp32.name))
    return path if path.is_file() else None


def choose_form(fp32: Path, precision: str = DEFAULT_PRECISION) -> tuple[Path, str]:
    """The file to run for the model ``fp32`` and why: ``precision`` auto takes its int8 form where the CPU
    has int8 dot products and the form exists, fp32 keeps the model, int8 demands the form (VprError if
    there is none). Returns (path, reason), e.g. (X.int8.onnx, "int8: AVX512-VNNI")."""
    if precision not in PRECISIONS:
        raise InputError("{opt.precision} {precision}: choose from {names}", precision=precision,
                         names=", ".join(PRECISIONS))
    if precision == "fp32":
        return fp32, "fp32: asked for"
    sibling = int8_sibling(fp32)
    if precision == "int8":
        if sibling is None:
            raise VprError(f"{fp32}: no int8 form of this model beside it ({int8_form(fp32.name)}, made by "
                           f"vpr_edge_export.quantize from this file)")
        return sibling, "int8: asked for"
    dot = int8_dot_product()
    if dot is None:
        return fp32, f"fp32: this {platform.machine() or 'CPU'} has no int8 dot-product instructions"
    if sibling is None:
        return fp32, f"fp32: no int8 form beside the model ({dot} available)"
    return sibling, f"int8: {dot}"
