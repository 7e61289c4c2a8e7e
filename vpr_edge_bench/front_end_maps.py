"""The front ends ``front-end-cache`` compares, as maps: each front end's map of a derived-streams folder's
references, built with the library's ``build-map`` options or (``gem``, ``random``) with an ONNX model exported by
``vpr_edge_export.onnx_export`` (the model files kept in a ``models`` folder, each exported once).

``ensure_map`` is the one entry: front end name -> OUT/D/F/map.npz (``pixels`` and ``noisy`` have none of their
own); a model export that fails raises ``FrontEndFailed`` with the exporter's last error line.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

from vpr_edge.map.make import BuildOptions, plan_map, write_map
from vpr_edge_bench.folder import StreamsFolder

FRONTS: tuple[str, ...] = ("ifv", "ifv128", "hog", "sift", "ldb", "pixels", "gem", "random", "noisy")
MODEL_SIZE = (160, 120)          # the global models' input, width x height
BACKBONE, TAP = "efficientnet_lite0", "stage5"


class FrontEndFailed(Exception):
    """A front end that could not be built (its one-line reason)."""


def build_with(refs: Path, out: Path, options: BuildOptions) -> None:
    """``build-map`` with ``options`` on ``refs`` into ``out`` (the library's plan + write)."""
    print(write_map(plan_map(refs, out, options)), flush=True)


def run_exporter(args: list[str], out: Path) -> None:
    """``python -m vpr_edge_export.onnx_export ARGS --out OUT``; FrontEndFailed with its last error line if it
    fails."""
    out.parent.mkdir(parents=True, exist_ok=True)
    args = [*args, "--out", str(out)]
    proc = subprocess.run([sys.executable, "-m", "vpr_edge_export.onnx_export", *args], capture_output=True,
                          text=True)
    if proc.returncode:
        lines = [ln for ln in (proc.stderr or proc.stdout).splitlines() if ln.strip()]
        raise FrontEndFailed(f"onnx_export exited {proc.returncode}: {lines[-1] if lines else 'no message'}")


def export_gem(models: Path) -> Path:
    """The pretrained EfficientNet-Lite0/stage5 + GeM ONNX (exported once into ``models``)."""
    out = models / f"gem_{MODEL_SIZE[0]}x{MODEL_SIZE[1]}.onnx"
    if not out.is_file():
        run_exporter(["--architecture", "gem", "--backbone", BACKBONE, "--tap", TAP, "--width", str(MODEL_SIZE[0]),
                      "--height", str(MODEL_SIZE[1])], out)
    return out


def random_weights(path: Path, seed: int) -> None:
    """A state dict of the backbone cut at TAP with seeded random weights, saved to ``path``. Convolutions are
    Kaiming-normal over their fan-in (PyTorch's default init shrinks the activations ~1e6-fold by stage5, and
    GeM's clamp then makes every descriptor alike); batch norms are left at identity statistics."""
    import torch
    from torch import nn

    from vpr_edge_export.backbones import BACKBONES

    torch.manual_seed(seed)
    net = BACKBONES[BACKBONE].build(TAP)
    for module in net.modules():
        if isinstance(module, nn.Conv2d):
            nn.init.kaiming_normal_(module.weight, mode="fan_in", nonlinearity="relu")
            if module.bias is not None:
                nn.init.zeros_(module.bias)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    torch.save(net.state_dict(), tmp)
    os.replace(tmp, path)


def export_random(models: Path, seed: int) -> Path:
    """The random-weight counterpart of ``export_gem``: the same network and exporter, ``--weights`` random."""
    out = models / f"random_seed{seed}_{MODEL_SIZE[0]}x{MODEL_SIZE[1]}.onnx"
    if not out.is_file():
        weights = models / f"{BACKBONE}_{TAP}_random_seed{seed}.pt"
        if not weights.is_file():
            random_weights(weights, seed)
        run_exporter(["--architecture", "gem", "--backbone", BACKBONE, "--tap", TAP, "--weights", str(weights),
                      "--width", str(MODEL_SIZE[0]), "--height", str(MODEL_SIZE[1])], out)
    return out


def ensure_map(front: str, folder: StreamsFolder, out: Path, models: Path, threads: int, seed: int
               ) -> Path | None:
    """OUT/D/F/map.npz of front end ``front`` for dataset ``folder`` (built unless it exists); None for a
    front end without a map of its own (pixels; noisy reads ifv's)."""
    if front in ("pixels", "noisy"):
        return None
    path = out / "map.npz"
    if path.is_file():
        return path
    out.mkdir(parents=True, exist_ok=True)
    refs = folder.ref
    t0 = time.perf_counter()
    if front == "ifv":
        tmp = path.with_name(".map.tmp.npz")
        shutil.copyfile(folder.map, tmp)
        os.replace(tmp, path)
    elif front == "ifv128":
        build_with(refs, path, BuildOptions(components=128, pca_dim=0, threads=threads))
    elif front in ("hog", "sift"):
        build_with(refs, path, BuildOptions(features=front, encoding="ifv", threads=threads))
    elif front == "ldb":
        build_with(refs, path, BuildOptions(features="ldb", encoding="none", threads=threads))
    elif front == "gem":
        build_with(refs, path, BuildOptions(model=export_gem(models), threads=threads))
    elif front == "random":
        build_with(refs, path, BuildOptions(model=export_random(models, seed), threads=threads))
    else:
        raise ValueError(f"unknown front end {front!r}")
    print(f"{path}: built in {time.perf_counter() - t0:.1f} s", flush=True)
    return path

