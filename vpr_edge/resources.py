"""What the package ships: the bundled ONNX feature models and the Corridor demo sample, found through
``importlib.resources`` so that they are read from wherever the package is installed (a wheel, an editable
checkout), never from the current directory."""
from __future__ import annotations

import os
import shutil
from importlib.resources import files
from pathlib import Path

from vpr_edge.errors import VprError

DEFAULT_MODEL_FILE = "efficientnet_lite0_stage5_320x240.onnx"
# the same tap exported at a quarter of the pixels, for small cameras (docs/results.md, "Input size")
SMALL_MODEL_FILE = "efficientnet_lite0_stage5_160x120.onnx"
SAMPLES = ("corridor",)


def _path(*parts: str) -> Path:
    """A file or folder shipped inside the package, as a file-system path (onnxruntime and OpenCV open
    paths). The package is always installed unzipped (``zip-safe`` is off), so this is its real location."""
    return Path(os.fspath(files("vpr_edge").joinpath(*parts)))


def bundled_model(name: str = DEFAULT_MODEL_FILE) -> Path:
    """Path of a bundled ONNX model (``DEFAULT_MODEL_FILE`` or ``SMALL_MODEL_FILE``)."""
    return _path("models", name)


def sample_folder(name: str = "corridor") -> Path:
    """The bundled sample ``name``: ``ref/``, ``query/``, ``ground_truth.csv`` and ``positions.csv`` (synthetic;
    its ReadMe.txt says how it was drawn). Read it, do not write it."""
    if name not in SAMPLES:
        raise VprError(f"unknown sample {name!r}; choose from {', '.join(SAMPLES)}")
    return _path("samples", name)


def copy_sample(dest: str | os.PathLike[str], name: str = "corridor") -> Path:
    """Copy the bundled sample ``name`` to the new folder ``dest`` (refused if it exists: nothing is ever
    written over); returns ``dest``. The copy is made beside ``dest`` and renamed into place."""
    dest = Path(dest)
    if dest.exists():
        raise VprError(f"{dest}: already exists; give a new folder name (nothing is written over)")
    if not dest.parent.is_dir():
        raise VprError(f"{dest}: folder {dest.parent} does not exist")
    tmp = dest.with_name(f".{dest.name}.tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        shutil.copytree(sample_folder(name), tmp)
        os.replace(tmp, dest)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return dest
