"""Global descriptors as frames: what NetVLAD, CosPlace, EigenPlaces, MixVPR or hloc users already hold, one
vector per image, instead of images. Two layouts:

* ``.npy``: a 2-D float16 / float32 / float64 array, one row per frame in stream order, read memory-mapped
  and never unpickled; frames are named by their row number (``000000``, ``000001`` ...);
* ``.h5`` / ``.hdf5`` (hloc's ``global-feats`` files; the ``h5`` extra, h5py): one group per image whose
  dataset ``global_descriptor`` is the vector, the group's path the frame's name, in name order.

Each frame is a ``Frame`` whose ``descriptor`` is its (D,) float32 vector. Every check (layout, dtype,
dimension, non-finite rows, objects) is made before the first frame comes, naming the file.
"""
from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from vpr_edge.errors import VprError
from vpr_edge.frames.frame import Frame

DESCRIPTOR_SUFFIXES = (".npy", ".h5", ".hdf5")
H5_DATASET = "global_descriptor"   # hloc's name for an image's global descriptor
CHECK_ROWS = 65_536                # rows a block when checking for non-finite values


def is_descriptor_file(path: str | os.PathLike[str]) -> bool:
    """True for a path whose suffix names a descriptor file (whether or not it exists)."""
    return Path(path).suffix.lower() in DESCRIPTOR_SUFFIXES


def require_h5py(path: str | os.PathLike[str]) -> None:
    """VprError naming ``path`` unless h5py (the ``h5`` extra) is installed."""
    import importlib.util

    if importlib.util.find_spec("h5py") is None:
        raise VprError(f"{path}: reading .h5 descriptors needs h5py: pip install 'vpr-edge[h5]'")


def _checked(path: Path, values: np.ndarray) -> np.ndarray:
    """``values`` if it is a non-empty (N, D) float array of finite values; else VprError naming ``path``."""
    if values.dtype.kind != "f" or values.ndim != 2 or 0 in values.shape:
        raise VprError(f"{path}: global descriptors must be a non-empty 2-D float array (frames x dims), got "
                       f"{values.ndim}-D {values.dtype} of shape {values.shape}")
    for i in range(0, len(values), CHECK_ROWS):
        bad = ~np.isfinite(values[i:i + CHECK_ROWS]).all(axis=1)
        if bad.any():
            raise VprError(f"{path}: row {i + int(np.argmax(bad))} holds NaN or infinite values")
    return values


def _open_npy(path: Path) -> np.ndarray:
    """A ``.npy`` memory-mapped, never unpickled (VprError naming ``path``); its values not yet checked."""
    try:
        values = np.load(path, mmap_mode="r", allow_pickle=False)
    except ValueError as e:
        if "allow_pickle" in str(e) or "object" in str(e).lower():
            raise VprError(f"{path}: holds Python objects, which vpr-edge never unpickles") from None
        raise VprError(f"{path}: not a readable .npy array ({str(e).splitlines()[0][:100]})") from None
    except (OSError, EOFError) as e:
        raise VprError(f"{path}: cannot read ({getattr(e, 'strerror', None) or e})") from None
    return values


def _read_h5(path: Path) -> tuple[np.ndarray, list[str]]:
    require_h5py(path)
    import h5py

    found: dict[str, np.ndarray] = {}
    try:
        with h5py.File(path, "r") as f:
            def visit(name: str, obj) -> None:
                if isinstance(obj, h5py.Dataset) and name.rsplit("/", 1)[-1] == H5_DATASET:
                    found[name.rsplit("/", 1)[0] if "/" in name else ""] = np.asarray(obj[()])
            f.visititems(visit)
    except (OSError, ValueError) as e:
        raise VprError(f"{path}: not a readable HDF5 file ({str(e).splitlines()[0][:100]})") from None
    if not found:
        raise VprError(f"{path}: no {H5_DATASET} datasets (hloc's layout: one group per image holding "
                       f"{H5_DATASET})")
    names = sorted(found)
    shapes = {np.squeeze(found[n]).shape for n in names}
    if len(shapes) != 1 or len(next(iter(shapes))) != 1:
        raise VprError(f"{path}: every {H5_DATASET} must be one vector of the same length, found shapes "
                       f"{sorted(shapes)[:3]}")
    values = np.stack([np.squeeze(found[n]) for n in names])
    return _checked(path, values), names


def read_descriptors(path: str | os.PathLike[str]) -> tuple[np.ndarray, list[str]]:
    """A descriptor file -> (values (N, D) float array, memory-mapped for ``.npy``; N frame names), checked
    (VprError naming the file: missing, wrong layout or dtype, NaN or infinite rows, objects)."""
    path = Path(path)
    if not path.is_file():
        raise VprError(f"{path}: no such descriptor file")
    if path.suffix.lower() == ".npy":
        values = _checked(path, _open_npy(path))
        return values, [f"{i:06d}" for i in range(len(values))]
    return _read_h5(path)


def descriptor_dims(path: str | os.PathLike[str]) -> int:
    """D of a descriptor file, read without going through its values (a ``.npy``'s header; an ``.h5``'s
    first vector); the values are checked where they are read (``read_descriptors``)."""
    path = Path(path)
    if path.suffix.lower() == ".npy":
        values = _open_npy(path)
        return int(values.shape[1]) if values.ndim == 2 else int(_checked(path, values).shape[1])
    require_h5py(path)
    import h5py

    try:
        with h5py.File(path, "r") as f:
            first = f.visititems(lambda name, obj: int(np.size(obj)) if isinstance(obj, h5py.Dataset) and
                                 name.rsplit("/", 1)[-1] == H5_DATASET else None)
    except (OSError, ValueError) as e:
        raise VprError(f"{path}: not a readable HDF5 file ({str(e).splitlines()[0][:100]})") from None
    return int(first) if first is not None else int(_read_h5(path)[0].shape[1])


def descriptor_frames(path: str | os.PathLike[str]) -> tuple[Iterator[Frame], int]:
    """The frames of a descriptor file (``read_descriptors``, checked first) and their count."""
    values, names = read_descriptors(path)

    def frames() -> Iterator[Frame]:
        for i, name in enumerate(names):
            yield Frame(i, name, None, descriptor=np.asarray(values[i], np.float32))
    return frames(), len(names)
