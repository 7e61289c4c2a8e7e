"""Map files: one ``.npz`` of plain arrays plus JSON metadata with a schema version (never pickled),
written atomically; older schemas are read and migrated on load, every file checked for consistency."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from vpr_edge.encoders import encoder_from_arrays
from vpr_edge.encoders.adapt import Adaptation
from vpr_edge.encoders.standardise import RouteMean
from vpr_edge.errors import VprError, warn
from vpr_edge.features.registry import MAP_FRONT_ENDS
from vpr_edge.features.resize import RESIZE
from vpr_edge.files.checks import is_special, output_target
from vpr_edge.files.npz import read_npz, write_npz
from vpr_edge.files.temps import dead_writers_files
from vpr_edge.index.encodings import DEFAULT_STORAGE, Encodings
from vpr_edge.index.ivf import IvfIndex
from vpr_edge.map.drives import Drives
from vpr_edge.map.model import PlaceMap, Svm
from vpr_edge.positions import Positions

MAP_SCHEMA = 6          # 6: adaptation gains (adapt_gain_*); 5: adaptation (adapt_*, "adapted"); 4: drives;
                        # 3: front end ("features"), encoder ("encoding")
READS_SCHEMAS = (1, 2, 3, 4, 5, 6)  # 2: IFV only, int8/float16/float32 encodings; 1: IFV, float32


def save_map(place_map: PlaceMap, path: str | os.PathLike[str], storage: str = DEFAULT_STORAGE) -> None:
    """Write the map atomically to ``path`` (a ``.npz`` file), encodings (and SVM weights) stored as
    ``storage`` (``index.encodings.STORAGES``: int8 with a per-row scale, float16, float32)."""
    m = place_map.repacked(storage)
    arrays = m.stored.to_arrays() | {"encoder_" + k: v for k, v in place_map.encoder.to_arrays().items()}
    meta = place_map.meta | {"kind": "map", "schema": MAP_SCHEMA, "names": place_map.names, "storage": storage,
                        "n_refs": len(place_map.names), "dim": int(place_map.stored.shape[1]), "features": place_map.features,
                        "descriptor_dim": place_map.encoder.input_dim,
                        "encoding": {"name": place_map.encoder.name, "params": place_map.encoder.params()},
                        "drives": place_map.drives.meta()}
    if place_map.positions is not None:
        arrays |= place_map.positions.to_arrays()
        meta["positions"] = place_map.positions.meta()
    else:
        meta.pop("positions", None)
    if place_map.index is not None:
        arrays |= place_map.index.to_arrays()
        meta["index"] = {"kind": "ivf", "lists": len(place_map.index.centroids)}
    else:
        meta.pop("index", None)
    if place_map.adaptation is not None:
        arrays |= place_map.adaptation.to_arrays()
        meta["adapted"] = place_map.meta.get("adapted") or {}
    else:
        meta.pop("adapted", None)
    stats = m.route_mean   # of the rows as stored: what a query is compared with
    arrays |= {"route_mean": stats.mean, "route_spread": stats.spread}
    if place_map.svm is not None:
        arrays |= {"svm_" + k: v for k, v in m.svm.weights.to_arrays().items()}
        arrays["svm_bias"] = place_map.svm.bias
        meta["svm"] = place_map.svm.meta
    write_npz(path, arrays, meta)


# metadata fields a map may hold, and the JSON types each must have (None: any); checked on load
_FIELDS: dict[str, tuple[type, ...]] = {
    "schema": (int,), "names": (list,), "storage": (str,), "n_refs": (int,), "dim": (int,),
    "descriptor_dim": (int,), "features": (dict,), "features_fingerprint": (str,), "encoding": (dict,),
    "model": (dict,), "model_file": (str,), "model_path": (str,), "model_sha256": (str,), "codebook": (dict,),
    "svm": (dict,), "appended": (list,), "refs_folder": (str,), "alpha": (int, float), "positions": (dict,),
    "drives": (list,), "index": (dict,), "adapted": (dict,),
}


def _check_meta(path: str | os.PathLike[str], meta: dict) -> None:
    """VprError naming the field when a map's metadata has a field of the wrong JSON type or value."""
    for key, kinds in _FIELDS.items():
        value = meta.get(key)
        if value is not None and (not isinstance(value, kinds) or isinstance(value, bool)):
            raise VprError(f"{path}: map metadata field {key!r} is a {type(value).__name__}, expected "
                           f"{' or '.join(k.__name__ for k in kinds)}")
    if not all(isinstance(n, str) for n in meta.get("names") or []):
        raise VprError(f"{path}: map metadata field 'names' holds something other than image names")
    for key in ("features", "encoding"):
        spec = meta.get(key) or {}
        if not isinstance(spec.get("name", ""), str) or not isinstance(spec.get("params") or {}, dict):
            raise VprError(f"{path}: map metadata field {key!r} needs a name (text) and params (an object)")
    front = meta.get("features") or {}
    if front and front.get("name") not in MAP_FRONT_ENDS:
        raise VprError(f"{path}: map names front end {front.get('name')!r}, which this release does not know "
                       f"({', '.join(MAP_FRONT_ENDS)})")
    resize = (front.get("params") or {}).get("resize")
    if resize is not None and resize not in RESIZE:
        raise VprError(f"{path}: map records resize policy {resize!r}, which this release does not know "
                       f"({', '.join(RESIZE)})")
    alpha = meta.get("alpha", 0.5)
    if not (isinstance(alpha, (int, float)) and 0.0 <= alpha <= 1.0):
        raise VprError(f"{path}: map metadata field 'alpha' must be a number in [0, 1]")


def load_map(path: str | os.PathLike[str], mmap: bool = False) -> PlaceMap:
    """Read a map, checking kind, schema version, every metadata field's type, finite stored values and
    internal consistency (VprError naming the file and the problem). With ``mmap`` the encodings stay in the
    file, memory-mapped, and the operating system pages references in as similarities touch them: an int8
    map (the default) opens reading its headers, metadata and row scales; a float16 / float32 map is read
    once through, a block at a time, to refuse non-finite values."""
    arrays, meta = read_npz(path, "map", READS_SCHEMAS, mmap=mmap)
    _check_meta(path, meta)
    left = [] if is_special(Path(path)) else dead_writers_files(output_target(Path(path)))
    if left:
        warn(f"{path}: {len(left)} file(s) beside it left by a build-map that died (e.g. {left[0].name}); the "
             "map is whole, and its next build-map removes them")
    try:
        return _assemble(path, arrays, meta)
    except (TypeError, ValueError, KeyError, AttributeError, IndexError) as e:   # a field this code missed
        raise VprError(f"{path}: map is inconsistent ({str(e).splitlines()[0][:120]})") from None


def _assemble(path: str | os.PathLike[str], arrays: dict[str, np.ndarray], meta: dict) -> PlaceMap:
    storage = meta.get("storage", "float32")
    try:
        stored = Encodings.from_arrays(arrays, storage)
    except ValueError as e:
        raise VprError(f"{path}: map is inconsistent ({e})") from None
    names = meta.get("names")
    if not isinstance(names, list) or len(names) != stored.shape[0]:
        raise VprError(f"{path}: map is inconsistent (encodings and names disagree)")
    if int(meta.get("schema", 0)) < 3:   # IFV maps: codebook_* arrays, alpha at the top level
        spec, prefix = {"name": "ifv", "params": {"alpha": meta.get("alpha", 0.5)}}, "codebook_"
        input_dim = int((meta.get("model") or {}).get("channels", -1))
    else:
        spec, prefix, input_dim = meta.get("encoding") or {}, "encoder_", int(meta.get("descriptor_dim", -1))
    small = {k[len(prefix):]: np.array(v) for k, v in arrays.items() if k.startswith(prefix)}  # into RAM
    encoder = encoder_from_arrays(spec, small, input_dim, str(path))
    if encoder.dim != stored.shape[1]:
        raise VprError(f"{path}: map is inconsistent ({encoder.name} gives {encoder.dim} dims, the encodings "
                       f"have {stored.shape[1]})")
    svm = None
    if "svm_bias" in arrays:
        try:
            weights = Encodings.from_arrays({k[4:]: v for k, v in arrays.items() if k.startswith("svm_")},
                                            storage)
        except ValueError as e:
            raise VprError(f"{path}: map's SVM is inconsistent ({e})") from None
        bias = np.asarray(arrays["svm_bias"], np.float32)
        if weights.shape != stored.shape or bias.shape != (stored.shape[0],):
            raise VprError(f"{path}: map's SVM is inconsistent (one classifier per reference expected)")
        svm = Svm(weights, bias, dict(meta.get("svm") or {}))
    positions = None
    if "positions" in arrays:
        if not isinstance(meta.get("positions"), dict):
            raise VprError(f"{path}: map metadata field 'positions' is missing beside its position arrays")
        try:
            positions = Positions.from_arrays(arrays, meta["positions"], len(names))
        except (ValueError, KeyError) as e:
            raise VprError(f"{path}: map's positions are inconsistent ({e})") from None
    drives = None if meta.get("drives") is None else Drives.from_meta(meta["drives"], len(names), str(path))
    index = None
    if "index_order" in arrays:
        try:
            index = IvfIndex.from_arrays(arrays, len(names), stored.shape[1])
        except (ValueError, KeyError) as e:
            raise VprError(f"{path}: map's index is inconsistent ({e})") from None
    return PlaceMap(stored, names, encoder, meta, svm, positions, drives, index, _route_mean(path, arrays, stored),
                    _adaptation(path, arrays, meta, stored.shape[1]))


def _adaptation(path: str | os.PathLike[str], arrays: dict[str, np.ndarray], meta: dict, dim: int
                ) -> Adaptation | None:
    """The map's learned adaptation (``encoders.adapt``; None: not adapted), checked against the encodings
    and the metadata that says what it was learned on."""
    held = [k for k in ("adapt_basis", "adapt_keep") if k in arrays]
    if not held and meta.get("adapted") is None:
        return None
    if len(held) < 2 or meta.get("adapted") is None:
        raise VprError(f"{path}: map is inconsistent (its adaptation needs adapt_basis, adapt_keep and the "
                       "'adapted' metadata together)")
    drives = meta["adapted"].get("drives", [])
    if not isinstance(drives, list) or not all(isinstance(d, dict) for d in drives):
        raise VprError(f"{path}: map metadata field 'adapted' needs a list of drives (objects)")
    try:
        return Adaptation.from_arrays(arrays, dim)
    except ValueError as e:
        raise VprError(f"{path}: map's adaptation is inconsistent ({e})") from None


def _route_mean(path: str | os.PathLike[str], arrays: dict[str, np.ndarray], stored: Encodings) -> RouteMean | None:
    """The references' statistics the file holds (``encoders.standardise``; None: a map written before
    them), checked against the encodings."""
    if "route_mean" not in arrays and "route_spread" not in arrays:
        return None
    try:
        mean = np.asarray(arrays["route_mean"], np.float32)
        spread = np.asarray(arrays["route_spread"], np.float32)
    except KeyError as e:
        raise VprError(f"{path}: map is inconsistent ({e.args[0]} missing beside its pair)") from None
    r, d = stored.shape
    if mean.shape != (d,) or spread.shape != (r,) or not (np.isfinite(mean).all() and np.isfinite(spread).all()) \
            or (spread <= 0).any():
        raise VprError(f"{path}: map is inconsistent (the references' mean {mean.shape} and spread "
                       f"{spread.shape} do not fit {r} x {d} encodings)")
    return RouteMean(mean, spread)
