"""build-map's options as one record (``BuildOptions``), and what follows from them alone: each drive's
positions and timestamps (``per_drive``), the codebook fit's settings (``fit_settings``) and the options
that only a fit uses (``fit_inputs``). Inputs are named as the fields are (``errors.InputError``)."""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from vpr_edge.encoders import FitSettings
from vpr_edge.errors import InputError, Message
from vpr_edge.features.conventions import GivenConventions


@dataclass(frozen=True)
class BuildOptions:
    """build-map's options; None = not given (the default applies, or with ``append`` the map's own)."""

    features: str | None = None
    encoding: str | None = None
    model: Path | None = None
    resize: str | None = None
    codebook: Path | None = None
    components: int | None = None
    pca_dim: int | None = None
    whiten: bool | None = None
    alpha: float | None = None
    tfidf: bool | None = None
    max_descriptors: int | None = None
    fit_iterations: int | None = None
    svm: bool = False
    seed: int = 0
    save_codebook: Path | None = None
    storage: str | None = None
    positions: tuple[str, ...] = ()      # per drive a CSV or GPX file, or ("exif",): the images' GPS tags
    timestamps: tuple[Path, ...] = ()    # per drive its frames' times (frame,stamp CSV), for a GPX track
    topic: str | None = None         # a drive is a ROS bag: its image topic
    positions_topic: str | None = None   # ... and its NavSatFix / Odometry topic
    append: bool = False
    inputs: GivenConventions = GivenConventions()   # a model without vpr_edge metadata: its input conventions
    batch_size: int = 8
    threads: int = 0
    ray: str | None = None     # describe and encode on this Ray cluster (local, auto, HOST:PORT, ray://HOST:PORT)
    index: str | None = None   # ivf, none; None: ivf on maps of IVF_MIN_REFS places or more (index.ivf)
    strict: bool = False       # a drive's frames of more than one size: refused (else a warning)

    def __post_init__(self) -> None:   # one value given as such: one drive's
        for key in ("positions", "timestamps"):
            value = getattr(self, key)
            if value is None or isinstance(value, (str, os.PathLike)):
                object.__setattr__(self, key, () if value is None else (value,))


def named(inputs: list[str | Message]) -> Message:
    """Inputs listed by name, ``, `` between (a ``Message`` item as it is)."""
    return Message.join([i if isinstance(i, Message) else Message("{opt.%s}" % i) for i in inputs])


def fit_inputs(o: BuildOptions) -> list[Message]:
    """The options given that only a codebook fit uses, by name."""
    labels = (("{opt.components}", o.components), ("{opt.pca_dim}", o.pca_dim),
              ("{opt.whiten}/{opt.no_whiten}", o.whiten), ("{opt.max_descriptors}", o.max_descriptors),
              ("{opt.fit_iterations}", o.fit_iterations), ("{opt.tfidf}", o.tfidf))
    return [Message(label) for label, v in labels if v is not None]


def convention_inputs(c: GivenConventions) -> list[str]:
    """The input conventions stated (``features.conventions``), by name."""
    return [k for k, v in (("input_size", c.size), ("mean", c.mean), ("std", c.std), ("bgr", c.bgr or None),
                           ("layout", c.layout)) if v is not None]


def per_drive(o: BuildOptions, n: int) -> list[tuple[str | None, Path | None]]:
    """Each of ``n`` drives' positions and timestamps: as many as drives, in their order; one ``exif`` for
    them all; none. InputError otherwise."""
    def spread(values: tuple, key: str) -> list:
        if not values:
            return [None] * n
        if len(values) == n:
            return list(values)
        if key == "positions" and values == ("exif",):
            return ["exif"] * n
        tail = " (or {opt.positions} exif for all)" if key == "positions" else ""
        raise InputError("{opt." + key + "} {first}: given {count} time(s) for {n} drives: give one per drive, "
                         "in the drives' order" + tail, first=values[0], count=len(values), n=n)
    return list(zip(spread(o.positions, "positions"), spread(o.timestamps, "timestamps")))


def fit_settings(o: BuildOptions) -> FitSettings:
    """The codebook fit: the options over ``FitSettings``' defaults (``pca_dim`` 0: no PCA)."""
    d = FitSettings()
    pca_dim = d.pca_dim if o.pca_dim is None else None if o.pca_dim == 0 else o.pca_dim
    return FitSettings(o.components or d.n_components, pca_dim, d.whiten if o.whiten is None else o.whiten,
                       d.alpha if o.alpha is None else o.alpha, o.max_descriptors or d.max_descriptors,
                       o.fit_iterations or d.iterations, o.seed, bool(o.tfidf))


def parse_drive(text: str | os.PathLike[str]) -> tuple[str | None, Path]:
    """A drive as given -> (its name if given, its path): ``NAME=PATH`` names a drive (a path that exists as
    given is taken as a path, whatever it holds)."""
    text = os.fspath(text)
    name, sep, path = text.partition("=")
    if not sep or Path(text).exists() or not name:
        return None, Path(text)
    return name, Path(path)
