"""Every encoder by name: build-map's ``--encoding``, the map file and the tests read this table."""
from __future__ import annotations

import os

import numpy as np

from vpr_edge.encoders.base import Encoder, FitSettings, READS_CODEBOOK
from vpr_edge.encoders.fisher import FisherVector, ImprovedFisherVector
from vpr_edge.encoders.flat import Flatten
from vpr_edge.encoders.words import BagOfWords, Vlad
from vpr_edge.errors import VprError
from vpr_edge.files.npz import read_npz

ENCODERS: dict[str, type[Encoder]] = {c.name: c for c in (Flatten, BagOfWords, Vlad, FisherVector,
                                                          ImprovedFisherVector)}
DEFAULT_ENCODING = ImprovedFisherVector.name   # the thesis's Improved Fisher Vector


def encoder_class(name: str) -> type[Encoder]:
    """The registered encoder ``name``; ValueError listing the names if there is none."""
    try:
        return ENCODERS[name]
    except KeyError:
        raise ValueError(f"unknown encoding {name!r}; choose from {', '.join(ENCODERS)}") from None


def fit_encoder(name: str, local: np.ndarray, mask: np.ndarray | None, settings: FitSettings,
                n_local: int | None, binary: bool = False) -> Encoder:
    """Fit encoder ``name`` on reference descriptors ``local`` (R, N, K) (``mask`` (R, N) or None);
    ``n_local``: the front end's fixed N (None when it varies); ``binary``: the descriptors are ±1 bits
    (``FitSettings.for_descriptors``)."""
    from vpr_edge.encoders.fit import sample_descriptors

    cls = encoder_class(name)
    k = local.shape[-1]
    settings = settings.for_descriptors(k, binary)
    x = sample_descriptors(local, mask, settings.max_descriptors, settings.seed) if cls.needs_fit else \
        np.zeros((0, k))
    return cls.fit(x, settings, k, local=local, mask=mask, n_local=n_local)


def encoder_from_arrays(spec: dict, arrays: dict[str, np.ndarray], input_dim: int, source: str) -> Encoder:
    """Rebuild a stored encoder: ``spec`` {"name", "params"} from the file's JSON; VprError naming ``source``
    when the arrays are missing or inconsistent."""
    try:
        cls = encoder_class(str(spec.get("name")))
    except ValueError as e:
        raise VprError(f"{source}: {e}") from None
    for name, a in arrays.items():
        if not np.issubdtype(np.asarray(a).dtype, np.number) or not np.isfinite(a).all():
            raise VprError(f"{source}: codebook array {name} holds NaN, infinite or non-numeric values")
    params = spec.get("params") or {}
    if not isinstance(params, dict):
        raise VprError(f"{source}: codebook parameters are not a JSON object")
    try:
        return cls.from_arrays(arrays, dict(params), input_dim)
    except KeyError as e:
        raise VprError(f"{source}: {cls.name} codebook array {e} missing") from None
    except (ValueError, TypeError, AttributeError, IndexError) as e:
        raise VprError(f"{source}: codebook arrays are inconsistent ({e})") from None


def load_codebook(path: str | os.PathLike[str]) -> tuple[Encoder, dict]:
    """Read a standalone codebook file; returns (encoder, metadata). Schema-1 files are IFV codebooks."""
    arrays, meta = read_npz(path, "codebook", READS_CODEBOOK)
    spec = meta.get("encoding") or {"name": "ifv", "params": {"alpha": 0.5}}
    if not isinstance(spec, dict) or not isinstance(meta.get("input_dim", 0), int):
        raise VprError(f"{path}: codebook metadata is malformed (encoding, input_dim)")
    return encoder_from_arrays(spec, arrays, int(meta.get("input_dim", 0)), str(path)), meta
