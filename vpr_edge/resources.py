"""What the package ships: the bundled ONNX feature models and the Corridor demo sample, found through
``importlib.resources`` so that they are read from wherever the package is installed (a wheel, an editable
checkout), never from the current directory."""
from __future__ import annotations

import os
import shutil
from importlib.resources import files
from pathlib import Path

from vpr_edge.errors import VprError

LARGE_MODEL_FILE = "efficientnet_lite0_stage5_320x240.onnx"
# the same tap exported at a quarter of the pixels, for small cameras (docs/results.md, "The default")
SMALL_MODEL_FILE = "efficientnet_lite0_stage5_160x120.onnx"
# the bundled fp32 models by input (width, height); each has an int8 form beside it (int8_form)
MODEL_FILES = {(160, 120): SMALL_MODEL_FILE, (320, 240): LARGE_MODEL_FILE}
# without a camera frame to go by (build-map chooses by the references' size: features.choice)
DEFAULT_MODEL_FILE = SMALL_MODEL_FILE
# the bundled samples: the name ``vpr-edge sample NAME`` copies (and the folder it makes) -> what it holds
SAMPLES = {"corridor": "the Corridor dataset, Milford 2013: 111 reference and 111 query frames, 160x120"}


def _path(*parts: str) -> Path:
    """A file or folder shipped inside the package, as a file-system path (onnxruntime and OpenCV open
    paths). The package is always installed unzipped (``zip-safe`` is off), so this is its real location."""
    return Path(os.fspath(files("vpr_edge").joinpath(*parts)))


def bundled_model(name: str = DEFAULT_MODEL_FILE) -> Path:
    """Path of a bundled ONNX model (a ``MODEL_FILES`` value or its ``int8_form``)."""
    return _path("models", name)


def int8_form(name: str) -> str:
    """File name of the int8 form of the fp32 model file ``name`` (``vpr_edge_export.quantize``'s output,
    kept beside it): ``X.onnx`` -> ``X.int8.onnx``."""
    return name[:-len(".onnx")] + ".int8.onnx" if name.endswith(".onnx") else name + ".int8.onnx"


def sample_folder(name: str = "corridor") -> Path:
    """The bundled sample ``name``: ``ref/``, ``query/``, ``ground_truth.csv`` and ``positions.csv`` (synthetic;
    its ReadMe.txt says how it was drawn). Read it, do not write it."""
    if name not in SAMPLES:
        raise VprError(f"unknown sample {name!r}; choose from {', '.join(SAMPLES)}")
    return _path("samples", name)


def copy_sample(name: str = "corridor", dest: str | os.PathLike[str] | None = None) -> Path:
    """Copy the bundled sample ``name`` to the new folder ``dest`` (default: ``./NAME``; refused if it exists:
    nothing is ever written over); returns the folder. The copy is made beside ``dest`` and renamed into
    place. VprError for an unknown sample, before anything is written."""
    source = sample_folder(name)
    dest = Path(name if dest is None else dest)
    if dest.exists():
        raise VprError(f"{dest}: already exists; give a new folder name (nothing is written over)")
    if not dest.parent.is_dir():
        raise VprError(f"{dest}: folder {dest.parent} does not exist")
    tmp = dest.with_name(f".{dest.name}.tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        shutil.copytree(source, tmp)
        os.replace(tmp, dest)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return dest
