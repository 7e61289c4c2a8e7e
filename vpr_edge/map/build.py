"""Building a map from reference images: describe each once, fit the front end and the codebook on a
sample of them, encode every reference as it is described, optionally train an SVM per place."""
from __future__ import annotations

import tempfile
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path

import numpy as np

from vpr_edge import __version__
from vpr_edge.encoders import Encoder, FitSettings, fit_encoder
from vpr_edge.encoders.registry import DEFAULT_ENCODING
from vpr_edge.errors import VprError
from vpr_edge.features import FrontEnd
from vpr_edge.features.base import check_finite
from vpr_edge.frames.images import load_image
from vpr_edge.index.encodings import DEFAULT_STORAGE, EncodingWriter, Encodings
from vpr_edge.map.front import front_end_meta
from vpr_edge.map.model import PlaceMap, Svm

Progress = Callable[[int], None]
Seen = Callable[[int, np.ndarray], None]   # each reference image as it is decoded: (its index in files, RGB image)
# encodes the references files[order] in batches elsewhere (``map.fleet.encode_on_ray``): (files, order, front,
# encoder, batch_size, progress) -> (indices (b,), encodings (b, D)) pairs
EncodeElsewhere = Callable[[Sequence[Path], np.ndarray, FrontEnd, Encoder, int, "Progress | None"],
                           Iterable[tuple[np.ndarray, np.ndarray]]]


def described(files: Sequence[Path], order: np.ndarray, front: FrontEnd, batch_size: int,
              progress: Progress | None = None, seen: Seen | None = None
              ) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray | None]]:
    """The images ``files[order]``, ``batch_size`` at a time, through ``front``: yields (indices (b,),
    descriptors (b, N, K), mask (b, N) or None), each image given to ``seen`` first. VprError naming an
    unreadable file."""
    for i in range(0, len(order), batch_size):
        idx = order[i:i + batch_size]
        images = [load_image(files[j]) for j in idx]
        if seen is not None:
            for j, image in zip(idx, images):
                seen(int(j), image)
        x, m = front.local(images)
        check_finite(x, [str(files[j]) for j in idx], front.name)
        if progress:
            progress(len(idx))
        yield idx, x, m


def _svm(encodings: np.ndarray, storage: str, seed: int) -> Svm:
    """One linear SVM per place trained on the float32 reference encodings (R, D), weights kept as ``storage``."""
    from vpr_edge.matchers.svm import fit_svm

    weights, bias, svm_meta = fit_svm(encodings, seed=seed)
    return Svm(Encodings.pack(weights, storage), bias, svm_meta)


def extract_all(files: Sequence[Path], front: FrontEnd, folder: Path, batch_size: int = 8,
                progress: Progress | None = None, seen: Seen | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """Local descriptors of every image into memory-mapped files in ``folder``: (R, N, K) float32 and, for
    front ends with a varying number of descriptors, the mask (R, N) bool (else None)."""
    local = mask = None
    for idx, x, m in described(files, np.arange(len(files)), front, batch_size, progress, seen):
        if local is None:
            local = np.lib.format.open_memmap(folder / "local.npy", mode="w+", dtype=np.float32,
                                              shape=(len(files),) + x.shape[1:])
            if m is not None:
                mask = np.lib.format.open_memmap(folder / "mask.npy", mode="w+", dtype=bool,
                                                 shape=(len(files), x.shape[1]))
        local[idx] = x
        if mask is not None:
            mask[idx] = m
    assert local is not None
    return local, mask


FIT_POOL = 4   # a codebook is fitted on a random subset of references holding FIT_POOL x max_descriptors local
               # descriptors (all references on routes smaller than that), kept in RAM while the map is built


def _fit_pool(files: Sequence[Path], front: FrontEnd, settings: FitSettings, batch_size: int,
              progress: Progress | None, seen: Seen | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The references a codebook is fitted on: images drawn at random (``settings.seed``) until they hold
    ``FIT_POOL * settings.max_descriptors`` real descriptors, or all of them. Returns (indices (P,) sorted,
    local (P, N, K), mask (P, N) or None), in file order."""
    order = np.random.default_rng(settings.seed).permutation(len(files))
    want = FIT_POOL * settings.max_descriptors
    taken: list[np.ndarray] = []
    parts: list[tuple[np.ndarray, np.ndarray | None]] = []
    real = 0
    for idx, x, m in described(files, order, front, batch_size, progress, seen):
        taken.append(idx)
        parts.append((x, m))
        real += int(m.sum()) if m is not None else x.shape[0] * x.shape[1]
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
    if front.needs_fit:
        front = front.fit(local, settings.seed)
        local = front.select(local)
    if encoder is None:
        encoder = fit_encoder(encoding, local, mask, settings, front.n_local, front.binary)
    check_fits(encoder, front)
    return front, encoder, local


def check_fits(encoder: Encoder, front: FrontEnd, source: str = "") -> None:
    """VprError (naming the codebook file ``source``, if given) unless ``encoder`` takes the descriptors
    ``front`` gives."""
    if encoder.input_dim != front.dim:
        raise VprError(f"{source + ': ' if source else ''}codebook expects {encoder.input_dim}-dim descriptors "
                       f"but the {front.name} front end gives {front.dim}")


def check_codebook_fits(encoder: Encoder, meta: dict, front: FrontEnd, source: str) -> None:
    """VprError naming the codebook file ``source`` unless the codebook (``encoder`` and its file's ``meta``)
    was fitted on this front end's descriptors (the same model or handcrafted parameters; an int8 model may
    reuse the codebook of the fp32 model it was quantised from) and takes their dimension."""
    recorded = meta.get("features_fingerprint") or meta.get("model_sha256")
    described = (meta.get("features") or {}).get("name", "cnn")
    if described != front.name or recorded not in (None, front.fingerprint, front.source_fingerprint):
        raise VprError(f"{source}: codebook was fitted on {described} descriptors ({str(recorded)[:12]}), not "
                       f"on this {front.name} front end's ({front.fingerprint[:12]})"
                       f"{'; another model' if front.name == 'cnn' else ''}")
    check_fits(encoder, front, source)


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


def build_map(files: Sequence[Path], front: FrontEnd, encoding: str = DEFAULT_ENCODING,
              encoder: Encoder | None = None, settings: FitSettings = FitSettings(), batch_size: int = 8,
              svm: bool = False, storage: str = DEFAULT_STORAGE, progress: Progress | None = None,
              elsewhere: EncodeElsewhere | None = None, seen: Seen | None = None) -> PlaceMap:
    """Describe every reference image in ``files`` (in that order; see ``list_images``) with ``front`` and
    make the map, encodings kept as ``storage`` (``index.encodings.STORAGES``). Each image is described once: unless
    ``encoder`` is given, the codebook is first fitted on a random subset of the references (``_fit_pool``;
    all of them on small routes), then every other reference is encoded as it is extracted, so that memory
    and disk hold only the stored encodings, whatever the route's length (with ``svm`` also their float32
    copy, to train on). bow with tf-idf needs every reference's words to fit and goes through
    ``map_from_local``. With ``elsewhere`` the references outside the fit sample are described and encoded by
    it (a Ray cluster: ``map.fleet``) in the same batches. Each image decoded here goes to ``seen`` (its index
    in ``files``, the image). Raises VprError on an unreadable image or an encoder that does not fit the front
    end."""
    if not files:
        raise VprError("no reference images given")
    names, refs_folder = [f.name for f in files], str(Path(files[0]).parent)
    if encoder is None and encoding == "bow" and settings.tfidf:
        with tempfile.TemporaryDirectory(prefix="vpr-edge-") as tmp:
            local, mask = extract_all(files, front, Path(tmp), batch_size, progress, seen)
            place_map = map_from_local(local, mask, front, names, refs_folder, encoding, None, settings, svm)
        return place_map if storage == "float32" else place_map.repacked(storage)
    fitted = encoder is None
    pool, n_real = np.zeros(0, np.int64), 0
    if fitted or front.needs_fit:
        pool, local, mask = _fit_pool(files, front, settings, batch_size, progress, seen)
        n_real = int(mask.sum()) if mask is not None else local.size // local.shape[-1]
        front, encoder, local = _fit(front, local, mask, encoding, encoder, settings)
    assert encoder is not None
    check_fits(encoder, front)
    store = EncodingWriter(len(files), encoder.dim, storage, keep_float=svm)
    if len(pool):
        for i in range(0, len(pool), 32):
            store.put(pool[i:i + 32], encoder.transform(local[i:i + 32], None if mask is None else mask[i:i + 32]))
        del local, mask
    rest = np.setdiff1d(np.arange(len(files)), pool)
    if elsewhere is not None:
        for idx, encoded in elsewhere(files, rest, front, encoder, batch_size, progress):
            store.put(idx, encoded)
    else:
        for idx, x, m in described(files, rest, front, batch_size, progress, seen):
            store.put(idx, encoder.transform(x, m))
    classifier = _svm(store.floats, storage, settings.seed) if svm else None
    meta = _meta(front, encoder, fitted, settings, n_real, refs_folder)
    return PlaceMap(store.encodings(), names, encoder, meta, classifier)


DESCRIPTOR_BLOCK = 65_536   # descriptors encoded and stored a block at a time (bounded memory at any size)


def map_from_descriptors(values: np.ndarray | Sequence[np.ndarray], names: list[str],
                         source: str | Sequence[str], storage: str = DEFAULT_STORAGE) -> PlaceMap:
    """The map of places given as global descriptors ``values`` (R, D) computed elsewhere (a memory-mapped
    ``.npy`` or an hloc ``.h5``, ``frames.descriptor_files``; or several such arrays, one per drive, taken one
    after another, each from its ``source``): the ``descriptors`` front end of D dims, each vector
    L2-normalised (encoding ``none``) and stored as ``storage``, a block at a time, so that memory holds the
    stored map and one block whatever the route's length."""
    from vpr_edge.encoders.flat import Flatten
    from vpr_edge.features.descriptors import GivenDescriptors

    parts = [values] if isinstance(values, np.ndarray) else list(values)
    sources = [source] * len(parts) if isinstance(source, str) else list(source)
    front = GivenDescriptors(int(parts[0].shape[1]))
    encoder = Flatten(front.dim, 1)
    store = EncodingWriter(sum(len(p) for p in parts), encoder.dim, storage)
    at = 0
    for part, where in zip(parts, sources):
        for i in range(0, len(part), DESCRIPTOR_BLOCK):
            block = front.given(np.asarray(part[i:i + DESCRIPTOR_BLOCK]), where)
            store.put(np.arange(at, at + len(block)), encoder.transform(block))
            at += len(block)
    meta = _meta(front, encoder, False, FitSettings(), 0, sources[0])
    return PlaceMap(store.encodings(), list(names), encoder, meta)


def map_from_local(local: np.ndarray, mask: np.ndarray | None, front: FrontEnd, names: list[str], refs_folder: str,
                   encoding: str = DEFAULT_ENCODING, encoder: Encoder | None = None, settings: FitSettings = FitSettings(),
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
    classifier = _svm(encodings, "float32", settings.seed) if svm else None
    return PlaceMap(Encodings.pack(encodings, "float32"), names, encoder, meta, classifier)
