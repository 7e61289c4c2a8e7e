"""The map's data: reference encodings as stored, their names, the encoder that makes query encodings
comparable, metadata, and for ``--mode svm`` one classifier per place. File I/O is ``map.io``, the front end
a map's queries go through is ``map.front``, building one from images is ``map.build``."""
from __future__ import annotations

import os
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from vpr_edge.encoders import Encoder
from vpr_edge.encoders.adapt import Adaptation
from vpr_edge.encoders.standardise import RouteMean
from vpr_edge.errors import InputError, Message, VprError, warn
from vpr_edge.index.encodings import Encodings
from vpr_edge.index.ivf import IvfIndex
from vpr_edge.map.drives import Drives
from vpr_edge.positions import Positions

CNN = {"name": "cnn", "params": {}}


@dataclass(frozen=True)
class Svm:
    """One linear classifier per reference place: decision value of encoding q for place r is
    ``weights[r] . q + bias[r]``. ``weights`` stored like the encodings (``index.encodings.Encodings``)."""

    weights: Encodings
    bias: np.ndarray          # (R,) float32
    meta: dict

    def scores(self, queries: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """Encodings (B, D) -> decision values (B, R) float32 (of the places ``rows`` only, if given)."""
        return self.weights.similarity(queries, rows) + (self.bias if rows is None else self.bias[rows])


@dataclass(frozen=True)
class PlaceMap:
    """Reference encodings as stored (``index.encodings.Encodings``: unit rows, R x D), their image names, the
    encoder (``vpr_edge.encoders``), metadata (``features``: the front end's record; ``model_*`` for cnn;
    how the codebook was made), when built with ``--svm`` the per-place classifiers, when built with
    ``--positions`` where each reference place is (``positions.Positions``), and its ``drives``
    (``map.drives.Drives``; not given: the references are one drive, named after their folder), on large
    maps an index of whole-route candidates (``index.ivf.IvfIndex``), and once adapted (``vpr-edge adapt``)
    the learned ``adaptation``: the stored rows are mapped by it, and ``encode`` maps each query."""

    stored: Encodings
    names: list[str]
    encoder: Encoder
    meta: dict
    svm: Svm | None = None
    positions: Positions | None = None
    drives: Drives = None   # type: ignore[assignment]  # None -> one drive (set in __post_init__)
    index: IvfIndex | None = None   # whole-route candidates (``index.ivf``), on large maps
    stored_mean: RouteMean | None = None   # the references' statistics as the map file holds them (None: not held)
    adaptation: Adaptation | None = None   # learned from labelled drives (``encoders.adapt``): rows stored mapped

    def __post_init__(self) -> None:
        if self.drives is None:
            name = Path(str(self.meta.get("refs_folder") or "route")).name or "route"
            object.__setattr__(self, "drives", Drives.single(name, len(self.names), self.meta.get("refs_folder")))
        elif self.drives.n_refs != len(self.names):
            raise ValueError(f"drives cover {self.drives.n_refs} places, the map has {len(self.names)}")

    @property
    def encodings(self) -> np.ndarray:
        """All reference encodings as float32 (R, D) in RAM (for analysis; matching uses ``similarity``)."""
        return self.stored.dense()

    @cached_property
    def route_mean(self) -> RouteMean:
        """The references' mean unit encoding and each one's distance from it (``encoders.standardise``): as
        the map file holds them (build-map writes them), else one pass over the stored rows on first use."""
        return self.stored_mean if self.stored_mean is not None else RouteMean.of(self.stored.in_order)

    @property
    def features(self) -> dict:
        """The front end's record ({"name", "params"}); maps older than schema 3 are cnn."""
        return self.meta.get("features") or CNN

    def similarity(self, queries: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """Query encodings (B, D) -> cosine similarities to every reference (B, R) float32, or to the
        references ``rows`` (int array) only."""
        if queries.shape[-1] != self.stored.shape[1]:
            raise VprError(f"query encodings have {queries.shape[-1]} dims but the map's "
                           f"{self.features['name']} + {self.encoder.name} encodings have {self.stored.shape[1]}")
        return self.stored.similarity(queries, rows)

    def check_scores(self, kind: str, source: str | os.PathLike[str]) -> None:
        """VprError naming the map file ``source`` unless this map can give ``kind`` scores (``svm``: a map
        built with build-map --svm); checked before the work by every caller that scores a map."""
        if kind == "svm" and self.svm is None:
            raise InputError("{source}: mode svm needs a map built with build-map {opt.svm}", source=source)

    def scores(self, queries: np.ndarray, kind: str = "cosine", rows: np.ndarray | None = None) -> np.ndarray:
        """(B, R): ``cosine`` similarities, or ``svm`` decision values (VprError if the map has no SVM); of
        the references ``rows`` only if given."""
        if kind == "cosine":
            return self.similarity(queries, rows)
        if self.svm is None:
            raise InputError("this map has no SVM (build it with build-map {opt.svm})")
        self.similarity(queries[:0], rows)  # dimension check
        return self.svm.scores(queries, rows)

    def repacked(self, storage: str) -> "PlaceMap":
        """This map with its encodings (and SVM weights) stored as ``storage``."""
        def packed(e: Encodings) -> Encodings:
            return e if e.storage == storage else Encodings.pack(e.dense(), storage)

        svm = None if self.svm is None else Svm(packed(self.svm.weights), self.svm.bias, self.svm.meta)
        return PlaceMap(packed(self.stored), self.names, self.encoder, self.meta, svm, self.positions, self.drives,
                        self.index, adaptation=self.adaptation)

    def extended(self, more: "PlaceMap") -> "PlaceMap":
        """This map with ``more``'s drives after its own (``more`` encoded with this map's front end, encoder
        and model; VprError otherwise, or for a drive name the map has already). The result is in this map's
        storage: its stored rows are copied as they are (into RAM, never expanded to float32). An SVM is not
        carried over (its classifiers would need retraining on the whole route). On an adapted map ``more``'s
        rows are mapped by the map's adaptation (``more`` itself must not be adapted)."""
        if not self.encoder.same_as(more.encoder) or more.meta.get("features_fingerprint") != self.fingerprint:
            raise VprError("appended drives must be described and encoded with the map's own front end, "
                           "model and codebook")
        drives = self.drives.then(more.drives)
        if (self.positions is None) != (more.positions is None):
            raise InputError("the map has positions: give {opt.positions} for the appended drives too"
                             if self.positions is not None else
                             "the map has no positions: appended drives cannot bring some")
        positions = None if self.positions is None else self.positions.concat(more.positions)
        if self.svm is not None:
            warn(Message("the map's SVM is dropped by {opt.append} (rebuild with {opt.svm} to train it on the "
                         "whole route)"))
        meta = {k: v for k, v in self.meta.items() if k != "svm"}
        if more.adaptation is not None:
            raise VprError("appended drives must be plain encodings, not an adapted map's")
        rows = more.stored if self.adaptation is None else \
            Encodings.pack(self.adaptation.apply(more.stored.dense()), self.stored.storage)
        return PlaceMap(self.stored.concat(rows), self.names + more.names, self.encoder,
                        meta | {"vpr_edge_version": more.meta.get("vpr_edge_version")}, positions=positions,
                        drives=drives, adaptation=self.adaptation)

    def labels(self) -> dict[str, int]:
        """Each place's label (``DRIVE/NAME``; in a map of one drive its ``NAME`` too) -> its index, for ground
        truth that names references (``Drives.labels``)."""
        return self.drives.labels(self.names)

    def place_at(self, where: float) -> tuple[np.ndarray, float, float]:
        """Where the map's place at fractional reference ``where`` is (positions needed): (coords (2,), heading
        degrees or NaN, metres along its drive from the drive's first place); never between two drives."""
        assert self.positions is not None
        drive = self.drives.of_ref(int(where))
        coords, heading, along = self.positions.at(min(float(where), float(drive.last)))
        return coords, heading, along - float(self.positions.along()[drive.first])

    @property
    def fingerprint(self) -> str:
        """What identifies the front end: the model file's SHA-256 for cnn, a hash of the parameters else."""
        return str(self.meta.get("features_fingerprint") or self.meta.get("model_sha256"))

    def encode(self, local: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
        """Local descriptors (B, N, K) (mask (B, N) or None) -> query encodings (B, D) for this map (mapped by
        its adaptation, if adapted)."""
        encodings = self.encoder.transform(local, mask)
        return encodings if self.adaptation is None else self.adaptation.apply(encodings)
