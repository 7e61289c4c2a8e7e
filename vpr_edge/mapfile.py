"""The map: reference encodings plus everything needed to describe and encode a query the same way (front
end, encoder, and for ``--mode svm`` the classifier), in one file."""
from __future__ import annotations

import os
import tempfile
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vpr_edge import __version__
from vpr_edge.compact import EncodingWriter, Encodings
from vpr_edge.encoders import Encoder, FitSettings, encoder_from_arrays, fit_encoder
from vpr_edge.errors import VprError, warn
from vpr_edge.extract import resolve_model
from vpr_edge.features import FrontEnd, make_front_end
from vpr_edge.images import load_image
from vpr_edge.store import read_npz, write_npz

FIT_DESCRIPTORS = FitSettings.max_descriptors  # local descriptors sampled to fit a codebook (README "Fitting
FIT_ITERATIONS = FitSettings.iterations        # the codebook": as accurate as 100,000 / 100, ~10x faster)
MAP_SCHEMA = 3          # 3: front end ("features") and encoder ("encoding", arrays encoder_*) recorded; SVM
READS_SCHEMAS = (1, 2, 3)  # 2: IFV only, int8/float16/float32 encodings; 1: IFV, float32
CNN = {"name": "cnn", "params": {}}
Progress = Callable[[int], None]


@dataclass(frozen=True)
class Svm:
    """One linear classifier per reference place: decision value of encoding q for place r is
    ``weights[r] . q + bias[r]``. ``weights`` stored like the encodings (``compact.Encodings``)."""

    weights: Encodings
    bias: np.ndarray          # (R,) float32
    meta: dict

    def scores(self, queries: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """Encodings (B, D) -> decision values (B, R) float32 (of the places ``rows`` only, if given)."""
        return self.weights.similarity(queries, rows) + (self.bias if rows is None else self.bias[rows])


@dataclass(frozen=True)
class PlaceMap:
    """Reference encodings as stored (``compact.Encodings``: unit rows, R x D), their image names, the
    encoder (``vpr_edge.encoders``), metadata (``features``: the front end's record; ``model_*`` for cnn;
    how the codebook was made) and, when built with ``--svm``, the per-place classifiers."""

    stored: Encodings
    names: list[str]
    encoder: Encoder
    meta: dict
    svm: Svm | None = None

    @property
    def encodings(self) -> np.ndarray:
        """All reference encodings as float32 (R, D) in RAM (for analysis; matching uses ``similarity``)."""
        return self.stored.dense()

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

    def scores(self, queries: np.ndarray, kind: str = "cosine", rows: np.ndarray | None = None) -> np.ndarray:
        """(B, R): ``cosine`` similarities, or ``svm`` decision values (VprError if the map has no SVM); of
        the references ``rows`` only if given."""
        if kind == "cosine":
            return self.similarity(queries, rows)
        if self.svm is None:
            raise VprError("this map has no SVM (build it with build-map --svm)")
        self.similarity(queries[:0], rows)  # dimension check
        return self.svm.scores(queries, rows)

    def repacked(self, storage: str) -> "PlaceMap":
        """This map with its encodings (and SVM weights) stored as ``storage``."""
        def packed(e: Encodings) -> Encodings:
            return e if e.storage == storage else Encodings.pack(e.dense(), storage)

        svm = None if self.svm is None else Svm(packed(self.svm.weights), self.svm.bias, self.svm.meta)
        return PlaceMap(packed(self.stored), self.names, self.encoder, self.meta, svm)

    def save(self, path: str | os.PathLike[str], storage: str = "int8") -> None:
        """Write the map atomically to ``path`` (a ``.npz`` file), encodings (and SVM weights) stored as
        ``storage`` (``compact.STORAGES``: int8 with a per-row scale, float16, float32)."""
        m = self.repacked(storage)
        arrays = m.stored.to_arrays() | {"encoder_" + k: v for k, v in self.encoder.to_arrays().items()}
        meta = self.meta | {"kind": "map", "schema": MAP_SCHEMA, "names": self.names, "storage": storage,
                            "n_refs": len(self.names), "dim": int(self.stored.shape[1]), "features": self.features,
                            "descriptor_dim": self.encoder.input_dim,
                            "encoding": {"name": self.encoder.name, "params": self.encoder.params()}}
        if self.svm is not None:
            arrays |= {"svm_" + k: v for k, v in m.svm.weights.to_arrays().items()}
            arrays["svm_bias"] = self.svm.bias
            meta["svm"] = self.svm.meta
        write_npz(path, arrays, meta)

    @classmethod
    def load(cls, path: str | os.PathLike[str], mmap: bool = False) -> "PlaceMap":
        """Read a map, checking kind, schema version and internal consistency. With ``mmap`` the encodings
        stay in the file, memory-mapped: opening reads headers and metadata only, and the operating system
        pages references in as similarities touch them (a 100,000-place map opens in milliseconds)."""
        arrays, meta = read_npz(path, "map", READS_SCHEMAS, mmap=mmap)
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
        return cls(stored, names, encoder, meta, svm)

    def extended(self, more: "PlaceMap") -> "PlaceMap":
        """This map with ``more``'s references after its own (``more`` encoded with this map's front end,
        encoder and model; raises VprError otherwise). The result is in this map's storage: its stored rows
        are copied as they are (into RAM, never expanded to float32). An SVM is not carried over (its
        classifiers would need retraining on the whole route)."""
        if more.encoder is not self.encoder or more.meta.get("features_fingerprint") != self.fingerprint:
            raise VprError("appended references must be described and encoded with the map's own front end, "
                           "model and codebook")
        clash = sorted(set(self.names) & set(more.names))
        if clash:
            warn(f"{len(clash)} appended reference name(s) already in the map (e.g. {clash[0]}); results name "
                 f"references by index too")
        if self.svm is not None:
            warn("the map's SVM is dropped by --append (rebuild with --svm to train it on the whole route)")
        appended = self.meta.get("appended", []) + [{"folder": more.meta.get("refs_folder"),
                                                     "first_index": len(self.names), "count": len(more.names)}]
        meta = {k: v for k, v in self.meta.items() if k != "svm"}
        return PlaceMap(self.stored.concat(more.stored), self.names + more.names, self.encoder,
                        meta | {"appended": appended, "vpr_edge_version": more.meta.get("vpr_edge_version")})

    @property
    def fingerprint(self) -> str:
        """What identifies the front end: the model file's SHA-256 for cnn, a hash of the parameters else."""
        return str(self.meta.get("features_fingerprint") or self.meta.get("model_sha256"))

    def model_path(self, given: Path | None) -> Path:
        """The model to localise with: ``given``, else ``$VPR_EDGE_MODEL``, else the file the map was built
        with if it is still there, else the bundled default (see ``extract.resolve_model``)."""
        return resolve_model(given, Path(self.meta.get("model_path") or ""))

    def front_end(self, map_path: str | os.PathLike[str], model: Path | None = None, threads: int = 0) -> FrontEnd:
        """The front end this map's queries must go through (its model for cnn, checked: VprError naming
        ``map_path`` if it is another model; ``model`` given to a handcrafted map is an error too)."""
        name = self.features["name"]
        if name != "cnn":
            if model is not None:
                raise VprError(f"{map_path}: map was built with the {name} front end, which takes no model; "
                               f"drop --model")
            return make_front_end(name, spec=self.features)
        front = make_front_end("cnn", self.model_path(model), threads, spec=self.features)
        if front.fingerprint != self.meta.get("model_sha256"):
            m = self.meta.get("model", {})
            info = getattr(front, "info", {})
            raise VprError(
                f"{map_path}: map was built with model {m.get('backbone')}/{m.get('tap')} "
                f"({self.meta.get('model_file')}, sha256 {str(self.meta.get('model_sha256'))[:12]}) but "
                f"{getattr(front, 'path', '?')} is {info.get('backbone')}/{info.get('tap')} "
                f"(sha256 {front.fingerprint[:12]}); pass --model with the map's model")
        return front

    def encode(self, local: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
        """Local descriptors (B, N, K) (mask (B, N) or None) -> query encodings (B, D) for this map."""
        return self.encoder.transform(local, mask)


def front_end_meta(front: FrontEnd) -> dict:
    """What a map records of its front end: its description, fingerprint, and for cnn the model's identity."""
    meta: dict = {"features": front.describe(), "features_fingerprint": front.fingerprint}
    path = getattr(front, "path", None)
    if front.name == "cnn" and path is not None:
        meta |= {"model": getattr(front, "info"), "model_file": path.name, "model_path": str(path.resolve()),
                 "model_sha256": front.fingerprint}
    return meta


def batched(files: Sequence[Path], size: int) -> Iterator[list[np.ndarray]]:
    """Decoded RGB images of ``files``, ``size`` at a time (VprError naming an unreadable file)."""
    for i in range(0, len(files), size):
        yield [load_image(f) for f in files[i:i + size]]


def extract_all(files: Sequence[Path], front: FrontEnd, folder: Path, batch_size: int = 8,
                progress: Progress | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """Local descriptors of every image into memory-mapped files in ``folder``: (R, N, K) float32 and, for
    front ends with a varying number of descriptors, the mask (R, N) bool (else None)."""
    local = mask = None
    row = 0
    for images in batched(files, batch_size):
        x, m = front.local(images)
        if local is None:
            local = np.lib.format.open_memmap(folder / "local.npy", mode="w+", dtype=np.float32,
                                              shape=(len(files),) + x.shape[1:])
            if m is not None:
                mask = np.lib.format.open_memmap(folder / "mask.npy", mode="w+", dtype=bool,
                                                 shape=(len(files), x.shape[1]))
        local[row:row + len(x)] = x
        if mask is not None:
            mask[row:row + len(x)] = m
        row += len(x)
        if progress:
            progress(len(x))
    assert local is not None
    return local, mask


FIT_POOL = 4   # a codebook is fitted on a random subset of references holding FIT_POOL x max_descriptors local
               # descriptors (all references on routes smaller than that), kept in RAM while the map is built


def _fit_pool(files: Sequence[Path], front: FrontEnd, settings: FitSettings, batch_size: int,
              progress: Progress | None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The references a codebook is fitted on: images drawn at random (``settings.seed``) until they hold
    ``FIT_POOL * settings.max_descriptors`` real descriptors, or all of them. Returns (indices (P,) sorted,
    local (P, N, K), mask (P, N) or None), in file order."""
    order = np.random.default_rng(settings.seed).permutation(len(files))
    want = FIT_POOL * settings.max_descriptors
    taken: list[np.ndarray] = []
    parts: list[tuple[np.ndarray, np.ndarray | None]] = []
    real = 0
    for i in range(0, len(files), batch_size):
        idx = order[i:i + batch_size]
        x, m = front.local([load_image(files[j]) for j in idx])
        taken.append(idx)
        parts.append((x, m))
        real += int(m.sum()) if m is not None else x.shape[0] * x.shape[1]
        if progress:
            progress(len(idx))
        if real >= want:
            break
    idx = np.concatenate(taken)
    sort = np.argsort(idx)
    local = np.concatenate([x for x, _ in parts])[sort]
    mask = None if parts[0][1] is None else np.concatenate([m for _, m in parts])[sort]
    return idx[sort], local, mask


def _fit(front: FrontEnd, local: np.ndarray, mask: np.ndarray | None, encoding: str, encoder: Encoder | None,
         settings: FitSettings) -> tuple[FrontEnd, Encoder, np.ndarray]:
    """Fit the front end (LDB's bit selection) and, unless ``encoder`` is given, the ``encoding`` codebook on
    reference descriptors ``local`` (R, N, K); returns them and ``local`` as the fitted front end gives it."""
    if getattr(front, "needs_fit", False):
        front = front.fit(local, settings.seed)  # type: ignore[attr-defined]
        local = front.select(local)              # type: ignore[attr-defined]
    if encoder is None:
        encoder = fit_encoder(encoding, local, mask, settings, front.n_local)
    _check_fits(encoder, front)
    return front, encoder, local


def _check_fits(encoder: Encoder, front: FrontEnd) -> None:
    """VprError unless ``encoder`` takes the descriptors ``front`` gives."""
    if encoder.input_dim != front.dim:
        raise VprError(f"codebook expects {encoder.input_dim}-dim descriptors but the {front.name} front end "
                       f"gives {front.dim}")


def _meta(front: FrontEnd, encoder: Encoder, fitted: bool, settings: FitSettings, n_real: int,
          refs_folder: str) -> dict:
    """A new map's metadata: the front end, how the codebook was made, where the references came from."""
    return front_end_meta(front) | {
        "codebook": {"fitted_on_refs": fitted, "n_components": encoder.n_components,
                     "pca_dim": int(encoder.pca.components.shape[0]) if encoder.pca is not None else None,
                     "seed": settings.seed}
                    | ({"descriptors": min(settings.max_descriptors, n_real), "iterations": settings.iterations}
                       if fitted and encoder.needs_fit else {}),
        "refs_folder": refs_folder,
        "vpr_edge_version": __version__,
    }


def build_map(files: Sequence[Path], front: FrontEnd, encoding: str = "ifv", encoder: Encoder | None = None,
              settings: FitSettings = FitSettings(), batch_size: int = 8, svm: bool = False,
              storage: str = "int8", progress: Progress | None = None) -> PlaceMap:
    """Describe every reference image in ``files`` (in that order; see ``list_images``) with ``front`` and
    make the map, encodings kept as ``storage`` (``compact.STORAGES``). Each image is described once: unless
    ``encoder`` is given, the codebook is first fitted on a random subset of the references (``_fit_pool``;
    all of them on small routes), then every other reference is encoded as it is extracted, so that memory
    and disk hold only the stored encodings, whatever the route's length (with ``svm`` also their float32
    copy, to train on). bow with tf-idf needs every reference's words to fit and goes through
    ``map_from_local``. Raises VprError on an unreadable image or an encoder that does not fit the front end."""
    if not files:
        raise VprError("no reference images given")
    names, refs_folder = [f.name for f in files], str(Path(files[0]).parent)
    if encoder is None and encoding == "bow" and settings.tfidf:
        with tempfile.TemporaryDirectory(prefix="vpr-edge-") as tmp:
            local, mask = extract_all(files, front, Path(tmp), batch_size, progress)
            place_map = map_from_local(local, mask, front, names, refs_folder, encoding, None, settings, svm)
        return place_map if storage == "float32" else place_map.repacked(storage)
    fitted = encoder is None
    pool, n_real = np.zeros(0, np.int64), 0
    if fitted or getattr(front, "needs_fit", False):
        pool, local, mask = _fit_pool(files, front, settings, batch_size, progress)
        n_real = int(mask.sum()) if mask is not None else local.size // local.shape[-1]
        front, encoder, local = _fit(front, local, mask, encoding, encoder, settings)
    assert encoder is not None
    _check_fits(encoder, front)
    store = EncodingWriter(len(files), encoder.dim, storage, keep_float=svm)
    if len(pool):
        for i in range(0, len(pool), 32):
            store.put(pool[i:i + 32], encoder.transform(local[i:i + 32], None if mask is None else mask[i:i + 32]))
        del local, mask
    rest = np.setdiff1d(np.arange(len(files)), pool)
    for i in range(0, len(rest), batch_size):
        idx = rest[i:i + batch_size]
        x, m = front.local([load_image(files[j]) for j in idx])
        store.put(idx, encoder.transform(x, m))
        if progress:
            progress(len(idx))
    classifier = None
    if svm:
        from vpr_edge.matchers.svm import fit_svm

        weights, bias, svm_meta = fit_svm(store.floats, seed=settings.seed)
        classifier = Svm(Encodings.pack(weights, storage), bias, svm_meta)
    meta = _meta(front, encoder, fitted, settings, n_real, refs_folder)
    return PlaceMap(store.encodings(), names, encoder, meta, classifier)


def map_from_local(local: np.ndarray, mask: np.ndarray | None, front: FrontEnd, names: list[str], refs_folder: str,
                   encoding: str = "ifv", encoder: Encoder | None = None, settings: FitSettings = FitSettings(),
                   svm: bool = False) -> PlaceMap:
    """The map of references described by ``front`` as ``local`` (R, N, K) (``mask`` (R, N) or None): fit the
    front end (LDB's bit selection, recorded in the map's ``features``) and the ``encoding`` codebook on them
    unless ``encoder`` is given, encode each reference (float32), and with ``svm`` train one linear SVM per
    place. For descriptors already extracted (the tools); ``build_map`` describes images and encodes as it goes."""
    fitted = encoder is None
    front, encoder, local = _fit(front, local, mask, encoding, encoder, settings)
    encodings = encoder.transform_chunked(local, mask)
    n_real = int(mask.sum()) if mask is not None else local.shape[0] * local.shape[1]
    meta = _meta(front, encoder, fitted, settings, n_real, refs_folder)
    classifier = None
    if svm:
        from vpr_edge.matchers.svm import fit_svm

        weights, bias, svm_meta = fit_svm(encodings, seed=settings.seed)
        classifier = Svm(Encodings.pack(weights, "float32"), bias, svm_meta)
    return PlaceMap(Encodings.pack(encodings, "float32"), names, encoder, meta, classifier)
