"""``vpr-edge adapt``: a map fitted to its route from labelled drives (``encoders.adapt``), written as a new map.

Every input is checked before any frame is encoded: the map (not adapted already), each drive's frame count
against its labels, the labels against the map, and the labelled frames' number. The new map is written
atomically, never over the map it was made from.
"""
from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from vpr_edge.encoders.adapt import MIN_PAIRS, SHRINK, Adaptation, Choice, fit_adaptation, middle_refs
from vpr_edge.errors import InputError, VprError, warn
from vpr_edge.files.checks import check_not_input, check_writable
from vpr_edge.files.one_writer import writer_lock
from vpr_edge.frames.frame import Frame
from vpr_edge.frames.images import open_stream
from vpr_edge.index.encodings import EncodingWriter
from vpr_edge.index.ivf import fit_ivf
from vpr_edge.map.io import save_map
from vpr_edge.map.model import PlaceMap
from vpr_edge.map.query import MapQuery

ALIGNED = "aligned"   # a drive's labels: frame i shows the map's place i
RADIUS_M = 10.0       # a drive's positions: references within this many metres are its frame's places


@dataclass(frozen=True)
class LabelledDrive:
    """A drive of the route and its labels: ``frames`` (a folder, video or descriptor file) and ``truth``:
    ``ALIGNED``, a ground-truth CSV or .npy (docs/formats.md), or a positions CSV of its frames (``positions``
    True: matched with the map's positions within ``radius`` metres)."""

    frames: str
    truth: str
    positions: bool = False
    radius: float = RADIUS_M


def drive_truth(drive: LabelledDrive, place_map: PlaceMap, frames: int) -> np.ndarray:
    """The drive's labels (Q, T) padded (-1: none) against ``place_map``, checked to fit its ``frames`` and the
    map's places (InputError, one line, before any frame is encoded)."""
    from vpr_edge.evaluation.truth import Truth

    n_refs = len(place_map.names)
    if drive.truth == ALIGNED:
        if frames != n_refs:
            raise InputError("{d}: {f} frames, but the map has {n} places: {opt.aligned} needs one frame a place",
                             d=drive.frames, f=frames, n=n_refs)
        return np.arange(n_refs, dtype=np.int64)[:, None]
    if drive.positions:
        if place_map.positions is None:
            raise InputError("{d}: labels by position need a map built with {opt.positions}", d=drive.truth)
        truth, _ = Truth(positions=("map", drive.truth), radius=drive.radius).load(place_map.positions)
    else:
        truth, shape = Truth(gt=drive.truth).load(None, place_map.labels)
        if shape is not None and shape[1] != n_refs:
            raise InputError("{t}: a matrix of {c} references, but the map has {n} places: labels of another "
                             "map?", t=drive.truth, c=shape[1], n=n_refs)
    if len(truth) != frames:
        raise InputError("{t}: {rows} labelled frames, but {d} has {f} frames: labels of another drive?",
                         t=drive.truth, rows=len(truth), d=drive.frames, f=frames)
    if truth.size and truth.max() >= n_refs:
        raise InputError("{t}: names place {r}, but the map has {n} places (0 to {last}): labels of another map?",
                         t=drive.truth, r=int(truth.max()), n=n_refs, last=n_refs - 1)
    if not (truth >= 0).any():
        where = f"within {drive.radius:g} m of the map's places" if drive.positions else "labelled with a place"
        raise InputError("{d}: no frame is {where}: a drive of another route?", d=drive.frames, where=where)
    return truth


def _frame_count(query: MapQuery, frames: str) -> int:
    """The drive's frame count, the drive checked against the map's kind of input."""
    query.check_source(frames)
    _, count = open_stream(frames)
    if count is None:
        raise InputError("{d}: a live source has no frame count: record the drive first", d=frames)
    return count


def adapt_map(map_path: str | os.PathLike[str], drives: Sequence[LabelledDrive], out: str | os.PathLike[str],
              rank: int | None = None, shrink: float = SHRINK, model: str | os.PathLike[str] | None = None,
              batch_size: int = 8, ort_threads: int = 0,
              on_skip: Callable[[Frame], None] = lambda frame: None) -> str:
    """Learn ``map_path``'s adaptation from the labelled ``drives`` (``encoders.adapt``) and write the adapted
    map to ``out`` (its rows mapped, its storage kept, an index refitted, an SVM dropped); returns a one-line
    summary. InputError, before any frame is encoded, for a map adapted already, an output over the map,
    labels that do not fit their drive or the map, or too few labelled frames."""
    if not drives:
        raise InputError("give at least one labelled drive")
    if (rank is not None and rank < 1) or shrink <= 0:
        raise InputError("{opt.rank} must be >= 1 and {opt.shrink} > 0, got {r} and {s}", r=rank, s=shrink)
    check_not_input({"the adapted map": out}, [map_path] + [p for d in drives for p in (d.frames, d.truth)
                                                          if p != ALIGNED])
    check_writable(out)
    query = MapQuery(map_path, model, ort_threads)
    source = query.map
    if source.adaptation is not None:
        raise InputError("{m}: adapted already (on {on}): adapt the map it was made from", m=map_path,
                         on=", ".join(d.get("frames", "?") for d in source.meta["adapted"].get("drives", [])))
    labelled = []
    for drive in drives:
        truth = drive_truth(drive, source, _frame_count(query, drive.frames))
        labelled.append((drive, middle_refs(truth)))
    pairs = sum(int((refs >= 0).sum()) for _, refs in labelled)
    if pairs < MIN_PAIRS:
        raise InputError("{d}: {p} labelled frames, too short to learn from (at least {n})",
                         d=", ".join(d.frames for d in drives), p=pairs, n=MIN_PAIRS)
    groups = source.encoder.groups()
    if groups is not None:
        require_scipy(map_path)
    with writer_lock(out, wait=False):
        q_enc, r_idx, used = [], [], []
        for drive, refs in labelled:
            frames, _ = open_stream(drive.frames)
            kept = 0
            for frame, e in query.encode_frames(frames, batch_size, on_skip):
                if frame.index < len(refs) and refs[frame.index] >= 0:
                    q_enc.append(e)
                    r_idx.append(int(refs[frame.index]))
                    kept += 1
            used.append({"frames": str(drive.frames), "labels": str(drive.truth), "pairs": kept})
        if len(q_enc) < MIN_PAIRS:
            raise VprError(f"{len(q_enc)} labelled frames could be decoded, too few to learn from (at least "
                           f"{MIN_PAIRS})")
        places = np.asarray(r_idx)
        adaptation, choice = fit_adaptation(np.stack(q_enc), source.stored.take(places).astype(np.float32), places,
                                            groups, rank, shrink)
        n_gains = 0 if adaptation.gain_in is None else int(groups.max()) + 1
        adapted = _adapted(source, adaptation, {"drives": used, "pairs": len(q_enc), "rank": len(adaptation.keep),
                                                "shrink": shrink, "gains": n_gains, "held_out": choice.scores})
        save_map(adapted, out, storage=source.stored.storage)
    return f"adapted {map_path} on {len(q_enc)} labelled frames of {len(drives)} drive(s): " + \
        summary(adaptation, choice, n_gains) + f" -> {out}"


def summary(adaptation: Adaptation, choice: Choice, n_gains: int) -> str:
    """What was learned and, where recipes were compared, why: one phrase; warns where no recipe beat the
    map as it is on the drive's held-out places."""
    what = f"{len(adaptation.keep)} directions whitened" + (f", {n_gains} codebook gains" if n_gains else "")
    if not choice.scores:
        return what
    kept, plain = choice.scores[choice.recipe.name], choice.scores["unadapted"]
    if kept <= plain:
        warn(f"adapting does not raise one frame's R@1 on the drive's held-out places ({kept:.3f} against "
             f"{plain:.3f} unadapted): compare the maps on a drive of your own")
    return f"{what} (one frame's R@1 on held-out places {kept:.3f}, unadapted {plain:.3f})"


def require_scipy(map_path: str | os.PathLike[str]) -> None:
    """InputError naming the missing extra unless SciPy is installed (an IFV or VLAD map's gains are fitted
    with its L-BFGS)."""
    try:
        import scipy.optimize  # noqa: F401
    except ImportError:
        raise InputError("{m}: adapting a codebook map fits its gains with SciPy (missing): pip install "
                         "'vpr-edge[fit]'", m=map_path) from None


def _adapted(source: PlaceMap, adaptation: Adaptation, adapted_meta: dict, block: int = 4096) -> PlaceMap:
    """``source`` with its rows mapped by ``adaptation`` (a block at a time, packed in its storage), an index
    refitted to them, an SVM dropped (its classifiers were trained on the rows before)."""
    writer = EncodingWriter(*source.stored.shape, source.stored.storage)
    for first, values in source.stored.blocks(block):   # a row's positive scale does not change its mapped row
        writer.put(np.arange(first, first + len(values)), adaptation.apply(values.astype(np.float32)))
    stored = writer.encodings()
    if source.svm is not None:
        warn("the map's SVM is dropped by adapt (its classifiers were trained on the rows before)")
    meta = {k: v for k, v in source.meta.items() if k != "svm"} | {"adapted": adapted_meta}
    index = None if source.index is None else fit_ivf(stored, len(source.index.centroids))
    return PlaceMap(stored, source.names, source.encoder, meta, None, source.positions, source.drives, index,
                    adaptation=adaptation)
