"""The map: reference encodings plus everything needed to encode a query the same way, in one file."""
from __future__ import annotations

import os
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vpr_edge import __version__
from vpr_edge.codebook import Codebook
from vpr_edge.compact import Encodings
from vpr_edge.encode import fisher_vector
from vpr_edge.errors import VprError, warn
from vpr_edge.extract import FeatureExtractor, resolve_model
from vpr_edge.images import load_image
from vpr_edge.store import read_npz, write_npz

FIT_DESCRIPTORS = 30_000  # local descriptors sampled to fit the GMM   (README "Fitting the codebook":
FIT_ITERATIONS = 30       # EM iterations at most                          as accurate as 100,000 / 100, ~10x faster)
MAP_SCHEMA = 2          # 2: encodings stored as int8 + per-row scale, float16 or float32 (meta "storage")
READS_SCHEMAS = (1, 2)  # 1: float32 encodings
Progress = Callable[[int], None]


@dataclass(frozen=True)
class PlaceMap:
    """Reference encodings as stored (``compact.Encodings``: L2-normalised IFVs, R x D), their image names,
    the codebook, and metadata: model identity (``model_sha256``, ``model``), ``alpha``, and how the
    codebook was made."""

    stored: Encodings
    names: list[str]
    codebook: Codebook
    meta: dict

    @property
    def encodings(self) -> np.ndarray:
        """All reference encodings as float32 (R, D) in RAM (for analysis; matching uses ``similarity``)."""
        return self.stored.dense()

    def similarity(self, queries: np.ndarray) -> np.ndarray:
        """Query encodings (B, D) -> cosine similarities to every reference (B, R) float32."""
        return self.stored.similarity(queries)

    @property
    def alpha(self) -> float:
        """Power-normalisation exponent used for the reference encodings (queries must use the same)."""
        return float(self.meta["alpha"])

    def save(self, path: str | os.PathLike[str], storage: str = "int8") -> None:
        """Write the map atomically to ``path`` (a ``.npz`` file), encodings stored as ``storage``
        (``compact.STORAGES``: int8 with a per-row scale, float16, float32)."""
        stored = self.stored if self.stored.storage == storage else Encodings.pack(self.stored.dense(), storage)
        meta = self.meta | {"kind": "map", "schema": MAP_SCHEMA, "names": self.names, "storage": storage,
                            "n_refs": len(self.names), "dim": int(stored.shape[1])}
        write_npz(path, stored.to_arrays() | self.codebook.to_arrays("codebook_"), meta)

    @classmethod
    def load(cls, path: str | os.PathLike[str], mmap: bool = False) -> "PlaceMap":
        """Read a map, checking kind, schema version and internal consistency. With ``mmap`` the encodings
        stay in the file, memory-mapped: opening reads headers and metadata only, and the operating system
        pages references in as similarities touch them (a 100,000-place map opens in milliseconds)."""
        arrays, meta = read_npz(path, "map", READS_SCHEMAS, mmap=mmap)
        try:
            stored = Encodings.from_arrays(arrays, meta.get("storage", "float32"))
        except ValueError as e:
            raise VprError(f"{path}: map is inconsistent ({e})") from None
        names = meta.get("names")
        if not isinstance(names, list) or len(names) != stored.shape[0]:
            raise VprError(f"{path}: map is inconsistent (encodings and names disagree)")
        channels = int((meta.get("model") or {}).get("channels", -1))
        small = {k: np.array(v) for k, v in arrays.items() if k.startswith("codebook_")}  # into RAM
        codebook = Codebook.from_arrays(small, channels, "codebook_", str(path))
        return cls(stored, names, codebook, meta)

    def extended(self, more: "PlaceMap") -> "PlaceMap":
        """This map with ``more``'s references after its own (``more`` encoded with this map's codebook and
        model; raises VprError otherwise). Loads this map's encodings into RAM to write the new file."""
        if more.codebook is not self.codebook or more.meta.get("model_sha256") != self.meta.get("model_sha256"):
            raise VprError("appended references must be encoded with the map's own model and codebook")
        clash = sorted(set(self.names) & set(more.names))
        if clash:
            warn(f"{len(clash)} appended reference name(s) already in the map (e.g. {clash[0]}); results name "
                 f"references by index too")
        dense = np.concatenate([self.stored.dense(), more.stored.dense()])
        appended = self.meta.get("appended", []) + [{"folder": more.meta.get("refs_folder"),
                                                     "first_index": len(self.names), "count": len(more.names)}]
        return PlaceMap(Encodings.pack(dense, "float32"), self.names + more.names, self.codebook,
                        self.meta | {"appended": appended, "vpr_edge_version": more.meta.get("vpr_edge_version")})

    def model_path(self, given: Path | None) -> Path:
        """The model to localise with: ``given``, else ``$VPR_EDGE_MODEL``, else the file the map was built
        with if it is still there, else the bundled default (see ``extract.resolve_model``)."""
        return resolve_model(given, Path(self.meta.get("model_path") or ""))

    def check_model(self, extractor: FeatureExtractor, map_path: str | os.PathLike[str]) -> None:
        """Raise VprError unless ``extractor`` is the model the map was built with."""
        if extractor.fingerprint != self.meta.get("model_sha256"):
            m = self.meta.get("model", {})
            raise VprError(
                f"{map_path}: map was built with model {m.get('backbone')}/{m.get('tap')} "
                f"({self.meta.get('model_file')}, sha256 {str(self.meta.get('model_sha256'))[:12]}) but "
                f"{extractor.path} is {extractor.info['backbone']}/{extractor.info['tap']} "
                f"(sha256 {extractor.fingerprint[:12]}); pass --model with the map's model")

    def encode(self, local: np.ndarray) -> np.ndarray:
        """Local descriptors (B, N, K) -> query encodings (B, D) compatible with this map."""
        return fisher_vector(local, self.codebook, self.alpha)


def _encode_all(local: np.ndarray, codebook: Codebook, alpha: float, chunk: int = 32) -> np.ndarray:
    return np.concatenate([fisher_vector(local[i:i + chunk], codebook, alpha) for i in range(0, len(local), chunk)])


def build_map(files: Sequence[Path], extractor: FeatureExtractor, codebook: Codebook | None = None,
              n_components: int = 128, pca_dim: int | None = None, whiten: bool = True, alpha: float = 0.5,
              max_descriptors: int = FIT_DESCRIPTORS, batch_size: int = 8, seed: int = 0,
              fit_iterations: int = FIT_ITERATIONS,
              progress: Progress | None = None) -> PlaceMap:
    """Extract local features of every reference image in ``files`` (in that order; see ``list_images``), fit
    a codebook on a random sample of them unless one is given, and encode each reference. Local features are
    staged in a temporary memory-mapped file so that RAM does not grow with the number of references.
    Raises VprError on an unreadable image."""
    if not files:
        raise VprError("no reference images given")
    if codebook is not None and codebook.input_dim != extractor.dim:
        raise VprError(f"codebook expects {codebook.input_dim}-dim descriptors but the model gives {extractor.dim}")
    n_local = int(extractor.info["grid_width"]) * int(extractor.info["grid_height"])
    fitted = codebook is None
    with tempfile.TemporaryDirectory(prefix="vpr-edge-") as tmp:
        local = np.lib.format.open_memmap(Path(tmp) / "local.npy", mode="w+", dtype=np.float32,
                                          shape=(len(files), n_local, extractor.dim))
        for i, feats in enumerate(extractor.iter_local_features((load_image(f) for f in files), batch_size)):
            local[i] = feats
            if progress:
                progress(1)
        if codebook is None:
            from vpr_edge_export.codebook_fit import fit_codebook

            flat = local.reshape(-1, extractor.dim)
            rng = np.random.default_rng(seed)
            rows = np.sort(rng.choice(len(flat), min(max_descriptors, len(flat)), replace=False))
            codebook = fit_codebook(flat[rows], n_components, pca_dim, whiten, max_descriptors, seed, fit_iterations)
            del flat
        encodings = _encode_all(local, codebook, alpha)
        del local
    meta = {
        "alpha": alpha,
        "model": extractor.info,
        "model_file": extractor.path.name,
        "model_path": str(extractor.path.resolve()),
        "model_sha256": extractor.fingerprint,
        "codebook": {"fitted_on_refs": fitted, "n_components": codebook.gmm.n_components,
                     "pca_dim": codebook.gmm.dim if codebook.pca is not None else None, "seed": seed}
                    | ({"descriptors": min(max_descriptors, len(files) * n_local), "em_iterations": fit_iterations}
                       if fitted else {}),
        "refs_folder": str(Path(files[0]).parent),
        "vpr_edge_version": __version__,
    }
    return PlaceMap(Encodings.pack(encodings, "float32"), [f.name for f in files], codebook, meta)
