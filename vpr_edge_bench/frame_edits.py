"""A cached stream as a camera that repeats or loses frames would deliver it (``front-end-lines --frames``).

- ``twice``: every frame comes twice, bit for bit (a video whose frame rate was raised by repeating frames);
  the copy's motion cue is 1, the same encoding again.
- ``drop:P``: each frame after the first is lost with probability P (a camera or a recording that drops
  frames). The kept frames keep their cached motion cue: after a lost frame a real cue would read a longer
  step, and both read as moving.
"""
from __future__ import annotations

import numpy as np

from vpr_edge_bench.front_end_streams import single_figures

EDITS = ("as-recorded", "twice", "drop:P")


def parse(how: str) -> tuple[str, float]:
    """``--frames``' value -> (edit, its probability); ValueError naming what is accepted."""
    if how in ("as-recorded", "twice"):
        return how, 0.0
    name, _, value = how.partition(":")
    try:
        p = float(value)
    except ValueError:
        p = -1.0
    if name != "drop" or not 0.0 < p < 1.0:
        raise ValueError(f"--frames must be one of {', '.join(EDITS)} with 0 < P < 1, got {how!r}")
    return name, p


def edited(case: dict[str, np.ndarray], how: str, seed: int = 0) -> dict[str, np.ndarray]:
    """A cached stream's arrays (``sim`` (Q, R), ``truth`` (Q, T), ``cue`` and ``one_view`` (Q,), ...) with its
    frames repeated or dropped (module docstring); the front end alone's R@1 counted again."""
    name, p = parse(how)
    n = len(case["sim"])
    if name == "as-recorded":
        return case
    if name == "twice":
        rows = np.repeat(np.arange(n), 2)
    else:
        keep = np.ones(n, bool)
        keep[1:] = np.random.default_rng(seed).random(n - 1) >= p
        rows = np.flatnonzero(keep)
    out = dict(case)
    out["sim"] = np.ascontiguousarray(np.asarray(case["sim"])[rows])
    out["truth"] = np.asarray(case["truth"])[rows]
    if "one_view" in case:
        out["one_view"] = np.asarray(case["one_view"])[rows]
    if "cue" in case:
        cue = np.asarray(case["cue"], np.float64)[rows]
        if name == "twice":
            cue[1::2] = 1.0   # the copy: the same encoding as the frame before
        out["cue"] = cue
    if (out["truth"] >= 0).any():
        out.update(single_figures(out["sim"], out["truth"], int(case.get("tolerance", 0))))
    return out
