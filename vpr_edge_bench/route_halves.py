"""A cached stream against one half of its map: a route the labelled drive did not see.

``front-end-lines --half`` scores every stream on one half of the map's references and fits the labelled
drive's line (``--calibrate-on``) on the other half, so that the drive and the streams share no place and no
image: what a team gets when it labels one stretch of road and drives another.
"""
from __future__ import annotations

import numpy as np

from vpr_edge_bench.front_end_streams import single_figures

HALVES = ("first", "second")
MIN_FRAMES = 20   # a stream with fewer frames of the half is left out (a partial route of the other half)


def half_bounds(references: int, half: str) -> tuple[int, int]:
    """The references [lo, hi) of ``half`` ("first" or "second") of a map of ``references`` places."""
    if half not in HALVES:
        raise ValueError(f"half must be one of {', '.join(HALVES)}, not {half!r}")
    mid = references // 2
    return (0, mid) if half == "first" else (mid, references)


def other_half(half: str) -> str:
    """The half that is not ``half``: where the labelled drive is fitted when the streams are scored on ``half``."""
    return HALVES[1 - HALVES.index(half)]


def cut_truth(truth: np.ndarray, lo: int, hi: int) -> np.ndarray:
    """``truth`` (Q, T) padded with -1, against the references [lo, hi) alone: entries inside shifted by -lo and
    first in their row, the others -1 (a frame with none is unmapped there) -> (Q, T) int64."""
    t = np.asarray(truth, np.int64)
    inside = (t >= lo) & (t < hi)
    order = np.argsort(~inside, axis=1, kind="stable")
    return np.take_along_axis(np.where(inside, t - lo, -1), order, axis=1)


def cut_stream(case: dict[str, np.ndarray], lo: int, hi: int,
               min_frames: int = MIN_FRAMES) -> dict[str, np.ndarray] | None:
    """A cached stream (``front-end-cache``'s arrays: ``sim`` (Q, R), ``truth`` (Q, T), ``cue`` (Q,),
    ``one_view`` (Q,), ``route`` (R,), ...) against the references [lo, hi) only: the frames from the first to the
    last whose truth lies there, with the stream's unmapped frames between them or next to them (a detour that
    leaves the map at the half's end stays a detour), the map's columns cut to match, the front end alone's R@1
    counted again. Foreign imagery (no frame mapped) keeps every frame. None where fewer than ``min_frames``
    frames have their truth in the half."""
    truth = cut_truth(case["truth"], lo, hi)
    mapped = (truth >= 0).any(axis=1)
    off = ~(np.asarray(case["truth"]) >= 0).any(axis=1)   # frames of no place of the whole map
    if off.all():   # foreign imagery: every frame, the half of the map
        rows = np.arange(len(truth))
    elif mapped.sum() < min_frames:
        return None
    else:
        at = np.flatnonzero(mapped)
        first, last = int(at[0]), int(at[-1])
        while first > 0 and off[first - 1]:
            first -= 1
        while last + 1 < len(off) and off[last + 1]:
            last += 1
        rows = np.arange(first, last + 1)
    out = dict(case)
    out["sim"] = np.ascontiguousarray(np.asarray(case["sim"])[rows, lo:hi])
    out["truth"] = truth[rows]
    for key in ("cue", "one_view"):
        if key in case:
            out[key] = np.asarray(case[key])[rows]
    if "route" in case:
        out["route"] = np.asarray(case["route"])[lo:hi]
    if mapped[rows].any():
        out.update(single_figures(out["sim"], out["truth"], int(case.get("tolerance", 0))))
    return out
