"""Where ``evaluate``'s similarity matrix comes from: a map and query frames (the product's own chain), SeqSLAM's
pixels (reference and query folders, no map), or a (Q, R) ``.npy`` file from any other tool."""
from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from vpr_edge.encoders.standardise import STANDARDISE, centred_stream
from vpr_edge.errors import VprError
from vpr_edge.frames.images import Frame, list_images, load_image, open_stream
from vpr_edge.index.encodings import Encodings
from vpr_edge.map.query import MapQuery
from vpr_edge.positions import Positions

OnSkip = Callable[[Frame], None]


@dataclass(frozen=True)
class Similarities:
    """What the matchers run on: ``cosine`` (Q, R) float64 (higher = more alike), ``svm`` (Q, R) decision
    values or None, ``kept`` (Q,) the query frame index of each row (frames that did not decode are left out;
    None: rows are frames 0..Q-1), ``encode_ms`` per frame (NaN when nothing was encoded here)."""

    cosine: np.ndarray
    svm: np.ndarray | None = None
    kept: np.ndarray | None = None
    encode_ms: float = float("nan")
    positions: Positions | None = None     # the references' (a map built with --positions)
    front: dict | None = None              # with a map: {"model": file run, "form": "int8: AVX512-VNNI", ...}
    encodings: np.ndarray | None = None    # with a map: (Q, D) the query encodings (each matcher's motion cue)
    references: Encodings | None = None    # with a map: its reference encodings (where its drive stood)


def sad_similarity(queries: np.ndarray, refs: np.ndarray, chunk: int = 16) -> np.ndarray:
    """(Q, D) and (R, D) descriptors -> (Q, R) similarity = minus the mean absolute difference."""
    out = np.empty((len(queries), len(refs)), np.float32)
    for i in range(0, len(queries), chunk):
        out[i:i + chunk] = -np.abs(queries[i:i + chunk, None, :] - refs[None, :, :]).mean(axis=2)
    return out


MAX_SIMILARITY = 1e100   # |value| a similarity file may hold: the matchers square and sum rows in float64


def from_file(path: str | os.PathLike[str]) -> Similarities:
    """A (Q, R) numeric ``.npy`` matrix (rows = queries), read without pickle; VprError naming ``path``."""
    try:
        sim = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as e:
        raise VprError(f"{path}: not a readable .npy matrix ({str(e).splitlines()[0][:100]})") from None
    real = np.issubdtype(sim.dtype, np.floating) or np.issubdtype(sim.dtype, np.integer)
    if sim.ndim != 2 or 0 in sim.shape or not real:
        raise VprError(f"{path}: similarity must be a non-empty 2-D real (queries x references) matrix, "
                       f"got shape {sim.shape} {sim.dtype}")
    if not np.isfinite(sim).all():
        raise VprError(f"{path}: similarity matrix holds NaN or infinite values")
    if sim.size and float(np.abs(sim).max()) > MAX_SIMILARITY:
        raise VprError(f"{path}: similarity values reach {float(np.abs(sim).max()):.3g}; beyond "
                       f"{MAX_SIMILARITY:.0e} the matchers' sums of squares overflow: scale the matrix")
    return Similarities(sim.astype(np.float64))


def _count_checked(queries: str | os.PathLike[str], n_truth: int, truth_src: str, topic: str | None = None):
    frames, count = open_stream(queries, topic=topic)
    if count is not None and count != n_truth:
        raise VprError(f"{queries}: {count} frames but the ground truth {truth_src} has {n_truth} rows")
    return frames


def _finish(queries: str | os.PathLike[str], kept: list[int], t0: float, cosine: np.ndarray,
            svm: np.ndarray | None = None, positions: Positions | None = None) -> Similarities:
    if not kept:
        raise VprError(f"{queries}: none of its frames could be decoded")
    return Similarities(cosine, svm, np.asarray(kept, np.int64), 1e3 * (time.perf_counter() - t0) / len(kept),
                        positions)


def from_pixels(refs: str | os.PathLike[str], queries: str | os.PathLike[str], n_truth: int, truth_src: str,
                on_skip: OnSkip, topic: str | None = None) -> Similarities:
    """SeqSLAM's front end (``features.patches.pixel_descriptor``) on the reference folder and the query
    frames, compared by minus the mean absolute difference. No motion cue: raw low-resolution pixels of a
    moving camera are often as alike as a stopped one's (docs/design.md, "Matching")."""
    from vpr_edge.features.patches import pixel_descriptor

    frames = _count_checked(queries, n_truth, truth_src, topic)
    ref_desc = np.stack([pixel_descriptor(load_image(f)) for f in list_images(refs)])
    t0 = time.perf_counter()
    kept, qd = [], []
    for frame in frames:
        if frame.image is None:
            on_skip(frame)
            continue
        kept.append(frame.index)
        qd.append(pixel_descriptor(frame.image))
    sim = sad_similarity(np.stack(qd), ref_desc).astype(np.float64) if qd else np.zeros((0, 0))
    return _finish(queries, kept, t0, sim)


def from_map(query: MapQuery, queries: str | os.PathLike[str], n_truth: int, truth_src: str, on_skip: OnSkip,
             batch_size: int = 8, svm: bool = False, topic: str | None = None,
             standardise: bool = STANDARDISE) -> Similarities:
    """The query frames encoded as the map's references were (``query``: the map opened with its front end,
    the chain ``Localizer`` runs), their cosine similarities to the map's references (``standardise``: of the
    standardised encodings, as ``map.search.FrameSearch`` computes them frame by frame), with ``svm`` the
    map's per-place SVM decision values, and each decoded frame's query encodings (from which each matcher's
    motion cue is computed, as ``localize`` computes it)."""
    frames = _count_checked(queries, n_truth, truth_src, topic)   # a descriptor file's values checked here
    query.check_source(queries)
    if svm:
        query.map.check_scores("svm", query.path)
    t0 = time.perf_counter()
    kept, enc = [], []
    for frame, e in query.encode_frames(frames, batch_size, on_skip):
        kept.append(frame.index)
        enc.append(e)
    if not enc:
        return _finish(queries, kept, t0, np.zeros((0, 0)))
    stacked = np.stack(enc)
    cosine = (standardised(query, stacked) if standardise else query.scores(stacked)).astype(np.float64)
    scores = query.scores(stacked, "svm").astype(np.float64) if svm else None
    return replace(_finish(queries, kept, t0, cosine, scores, query.map.positions), front=query.runs(),
                   encodings=stacked, references=query.map.stored)


def standardised(query: MapQuery, encodings: np.ndarray) -> np.ndarray:
    """A stream's encodings (Q, D) in order -> the cosines of the standardised pairs (Q, R) float32
    (``encoders.standardise``: each frame centred on the running mean of the frames before it)."""
    route = query.map.route_mean
    centred = centred_stream(encodings, route.mean)
    return route.scores(query.scores(centred), centred)
