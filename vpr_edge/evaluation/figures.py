"""The figures ``evaluate`` draws (the ``plot`` extra), each one PNG written atomically: every mode's PR curve
(``plot``), the similarity matrix with each mode's answers (``plot_matrix``) and where each mode puts the
vehicle (``plot_route``: on the route from the map's positions, else ``plot_progress``: the reference answered
against the frame). The same mode has the same colour in every figure; right / wrong / lost the same three
styles. The helpers above the drawing (axis limits, grid, counts) are pure and need no matplotlib."""
from __future__ import annotations

import math
import os
from collections.abc import Sequence

import numpy as np

from vpr_edge.evaluation.metrics import truth_middle
from vpr_edge.evaluation.scoring import ModeReport
from vpr_edge.files.atomic import atomic_output
from vpr_edge.positions import EARTH_RADIUS_M, Positions

DPI = 100
MAX_WIDTH_IN = 16.0      # no figure wider than this (inches at ``DPI``: 1600 px)
MAX_HEIGHT_IN = 12.0     # ... nor a grid of panels taller
MIN_WIDTH_IN = 6.4       # nor a grid narrower (room for the title and the legend)
# one colour per mode, told apart on white and on the matrix's grey: tab10 without its grey, then black
MODE_COLOURS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#bcbd22",
                "#17becf", "#000000")
MODE_MARKERS = "o^sDvP*Xh<"
KINDS = ("right", "wrong", "lost")
KIND_STYLE = {"right": ("#2ca02c", "o"), "wrong": ("#d62728", "X"), "lost": ("#5a5a5a", "s")}   # colour, marker
TRUTH_COLOUR = "#ffe066"                           # pale yellow: the ground truth's places, under the answers


def mode_colours(names: Sequence[str]) -> dict[str, str]:
    """One colour per mode, in order (``MODE_COLOURS``, cycled past ten)."""
    return {n: MODE_COLOURS[i % len(MODE_COLOURS)] for i, n in enumerate(names)}


def precision_floor(curves: Sequence[tuple[np.ndarray, np.ndarray]], useful: float = 0.1,
                    step: float = 0.05) -> float:
    """The PR axes' lowest precision: a little below the lowest precision any curve ((recall, precision)
    arrays, each (N,)) reaches at recall >= ``useful`` (a curve that never gets there: at its highest recall),
    rounded down to ``step``; 0 .. 1 - ``step``. The first few answers' precision (recall near 0) is left out."""
    lows = [float(p[r >= min(useful, float(r.max()))].min()) for r, p in curves if len(r)]
    if not lows:
        return 0.0
    floor = math.floor((min(lows) - step / 10) / step + 1e-9) * step
    return float(np.clip(round(floor, 6), 0.0, 1.0 - step))


def answer_kinds(rep: ModeReport) -> dict[str, np.ndarray]:
    """Each frame's answer as right / wrong / lost (``KINDS``), (Q,) bool each, one true per frame."""
    return {"right": rep.correct & ~rep.lost, "wrong": ~rep.correct & ~rep.lost, "lost": rep.lost.copy()}


def counts_text(name: str, kinds: dict[str, np.ndarray], sep: str = ": ") -> str:
    """'stream: 98 right, 3 wrong, 10 lost' (frames of each kind, ``answer_kinds``; ``sep`` after the name)."""
    return name + sep + ", ".join(f"{int(kinds[k].sum())} {k}" for k in KINDS)


def plane_xy(positions: Positions) -> np.ndarray:
    """(R, 2) metres east, north to draw a route in: local x, y as they are; latitude, longitude projected
    about the route's middle (equirectangular: exact enough across a route), relative to its first place."""
    if not positions.geo:
        return np.asarray(positions.coords, np.float64)
    rad = np.radians(np.asarray(positions.coords, np.float64))
    lat0 = float(np.nanmean(rad[:, 0]))
    north = (rad[:, 0] - rad[0, 0]) * EARTH_RADIUS_M
    east = (rad[:, 1] - rad[0, 1]) * EARTH_RADIUS_M * math.cos(lat0)
    return np.stack([east, north], axis=1)


def route_limits(xy: np.ndarray, margin: float = 0.05, min_ratio: float = 0.25,
                 min_span: float = 10.0) -> tuple[tuple[float, float], tuple[float, float]]:
    """Axis limits ((x0, x1), (y0, y1)) framing a route's (R, 2) points in metres (NaN rows ignored): its
    extent plus ``margin`` of its longer side each way, the shorter side widened about its middle to at least
    ``min_ratio`` of the longer (a straight route still gets a panel); a route within ``min_span`` (or a single
    place) framed ``min_span`` each way."""
    ok = np.isfinite(xy).all(axis=1)
    pts = xy[ok] if ok.any() else np.zeros((1, 2))
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    longest = max(float((hi - lo).max()), min_span)
    shortest = min_ratio * longest if (hi - lo).max() >= min_span else min_span
    half = np.maximum(hi - lo, shortest) / 2 + margin * longest
    mid = (lo + hi) / 2
    return (float(mid[0] - half[0]), float(mid[0] + half[0])), (float(mid[1] - half[1]), float(mid[1] + half[1]))


_PAD_W, _PAD_H, _FRAME_H = 0.75, 1.0, 1.0   # inches per panel for tick labels / for its title and x labels;
#                                             per figure for its title and the legend below


def grid_layout(n: int, aspect: float, max_box: float = 4.0, min_cell: float = 2.6) -> tuple[int, int, float, float]:
    """How to lay out ``n`` panels whose plot boxes are ``aspect`` (width / height): (columns, rows, cell
    width, cell height) in inches, the layout with the largest boxes that fits ``MAX_WIDTH_IN`` x
    ``MAX_HEIGHT_IN``, a box at most ``max_box`` on its longer side, a cell at least ``min_cell`` wide (room
    for its title)."""
    best: tuple[float, tuple[int, int, float, float]] | None = None
    for cols in range(1, max(n, 1) + 1):
        rows = -(-n // cols) or 1
        w = min(MAX_WIDTH_IN / cols - _PAD_W, max_box, max_box * aspect)
        h = min(w / aspect, (MAX_HEIGHT_IN - _FRAME_H) / rows - _PAD_H)
        w = h * aspect
        cell_w = max(w + _PAD_W, min_cell)
        if h <= 0 or (cols > 1 and cell_w * cols > MAX_WIDTH_IN):
            continue
        area = w * h * (1 - 0.02 * (cols * rows - n))       # an empty cell counts against a layout
        if best is None or area >= best[0] - 1e-9:          # a tie: the wider layout
            best = (area, (cols, rows, cell_w, h + _PAD_H))
    return best[1] if best else (1, 1, min_cell, 3.0)


def marker_sizes(n: int, cell_px: float) -> list[float]:
    """Marker widths in points for ``n`` modes over matrix cells ``cell_px`` pixels wide (at ``DPI``): from
    1.3 cells down to 0.45, so that each mode drawn over the ones before leaves a ring of them showing;
    2.5 .. 10 points each."""
    cell_pt = cell_px * 72 / DPI
    steps = np.linspace(1.3 * cell_pt, 0.45 * cell_pt, n) if n > 1 else np.array([cell_pt])
    return [float(v) for v in np.clip(steps, 2.5, 10.0)]


def _pyplot():
    """matplotlib.pyplot on the Agg back end (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: str | os.PathLike[str]) -> None:
    """Write ``fig`` as a PNG atomically and close it."""
    with atomic_output(path) as tmp:
        fig.savefig(tmp, format="png", dpi=DPI)
    _pyplot().close(fig)


def plot(path: str | os.PathLike[str], reports: dict[str, ModeReport], title: str) -> None:
    """All modes' PR curves in one PNG: the precision axis from a little below the lowest precision a curve
    reaches at useful recall (``precision_floor``), recall 0..1; the legend beside, best AUC first."""
    plt = _pyplot()
    colours = mode_colours(list(reports))
    ranked = sorted(reports.items(), key=lambda kv: -kv[1].auc if kv[1].auc == kv[1].auc else 1.0)
    fig, ax = plt.subplots(figsize=(9.6, 5.0), dpi=DPI)
    for k, (name, r) in enumerate(ranked):
        ax.plot(r.curve.recall, r.curve.precision, color=colours[name], linewidth=2.0,
                linestyle=("-", "--", "-.", ":")[k % 4], label=f"{name}  AUC {r.auc:.3f}")
    floor = precision_floor([(r.curve.recall, r.curve.precision) for r in reports.values()])
    ax.set_xlim(0, 1)
    ax.set_ylim(floor, 1.0 + (1.0 - floor) * 0.02)
    ax.set_xlabel("recall", fontsize=11)
    ax.set_ylabel("precision" + (f" (axis from {floor:.2f})" if floor > 0 else ""), fontsize=11)
    ax.tick_params(labelsize=10)
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=9, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False, handlelength=3)
    fig.tight_layout()
    _save(fig, path)


def _truth_mask(truth: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(Q, R) bool: the references the ground truth ((Q, K) reference indices, -1 padding) lists per frame."""
    mask = np.zeros(shape, bool)
    tq, tk = np.nonzero((truth >= 0) & (truth < shape[1]))
    mask[tq, truth[tq, tk]] = True
    return mask


def plot_matrix(path: str | os.PathLike[str], sim: np.ndarray, truth: np.ndarray,
                reports: dict[str, ModeReport], title: str) -> None:
    """The (Q, R) similarity matrix (queries down, references across; pale greys, darker = more alike) with
    the ground truth's references filled pale yellow under each mode's answers (a colour and a marker per
    mode; its right answers each smaller than the mode's before and drawn over them, so that answers in one
    cell show as rings (``marker_sizes``), its wrong ones large and on top; lost frames left out) and a
    legend with each mode's counts below. One PNG, written atomically."""
    plt = _pyplot()
    from matplotlib.colors import ListedColormap
    from mpl_toolkits.axes_grid1 import make_axes_locatable

    q, r = sim.shape
    shown = {n: rep for n, rep in reports.items() if rep.refs is not None}
    colours = mode_colours(list(reports))
    legend_rows = -(-(len(shown) + 1) // 2)
    fig, ax = plt.subplots(figsize=(float(np.clip(4.0 + r / 25, 6.5, 10.0)),
                                    float(np.clip(3.4 + q / 25, 5.0, 9.0)) + 0.25 * legend_rows), dpi=DPI)
    im = ax.imshow(sim, aspect="auto", cmap="Greys", alpha=0.55, interpolation="nearest")
    cax = make_axes_locatable(ax).append_axes("right", size="3%", pad=0.12)
    fig.colorbar(im, cax=cax).set_label("similarity (darker = more alike)", fontsize=9)
    mask = _truth_mask(truth, sim.shape)
    ax.imshow(np.ma.masked_where(~mask, mask), aspect="auto", cmap=ListedColormap([TRUTH_COLOUR]), alpha=0.9,
              interpolation="nearest")
    ax.scatter([], [], marker="s", s=40, color=TRUTH_COLOUR, label="ground truth")
    sizes = marker_sizes(len(shown), min(ax.bbox.width / r, ax.bbox.height / q))
    for k, (name, rep) in enumerate(shown.items()):
        kinds = answer_kinds(rep)
        style = {"marker": MODE_MARKERS[k % len(MODE_MARKERS)], "color": colours[name], "edgecolors": "white",
                 "linewidths": 0.4}
        for kind, size, z in (("right", sizes[k], 2 + k), ("wrong", max(sizes[0], 5.0), 20 + k)):
            at = np.flatnonzero(kinds[kind])
            ax.scatter(rep.refs[at], at, s=size ** 2, zorder=z, **style,
                       label=counts_text(name, kinds) if kind == "right" else None)
    ax.set_xlim(-0.5, r - 0.5)
    ax.set_ylim(q - 0.5, -0.5)
    ax.set_xlabel("reference (index in the map)", fontsize=10)
    ax.set_ylabel("query frame", fontsize=10)
    ax.set_title(title, fontsize=10)
    legend = ax.legend(fontsize=8.5, loc="upper center", bbox_to_anchor=(0.5, -0.08), ncol=2, frameon=False)
    for handle in legend.legend_handles:
        handle.set_sizes([45])                     # every mode's marker alike in the legend
    fig.tight_layout()
    _save(fig, path)


def _panels(n: int, cols: int, rows: int, cell: tuple[float, float], share: bool):
    """A figure of ``n`` panels in ``cols`` x ``rows`` cells of ``cell`` (width, height) inches, sharing
    their axes if ``share``, room above for the title and below for the legend; the unused cells hidden."""
    plt = _pyplot()
    size = (max(cell[0] * cols, MIN_WIDTH_IN), cell[1] * rows + _FRAME_H)
    fig, axes = plt.subplots(rows, cols, figsize=size, dpi=DPI, squeeze=False, sharex=share, sharey=share)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    return fig, list(axes.flat)[:n]


def _label_outer(axes: list, cols: int, xlabel: str, ylabel: str) -> None:
    """Axis labels on the left column and the bottom panel of each column only."""
    for i, ax in enumerate(axes):
        ax.tick_params(labelsize=8)
        if i + cols >= len(axes):
            ax.set_xlabel(xlabel, fontsize=9)
            ax.tick_params(labelbottom=True)
        if i % cols == 0:
            ax.set_ylabel(ylabel, fontsize=9)


def _finish_grid(fig, axes: list, title: str, path: str | os.PathLike[str]) -> None:
    """The figure's title, one legend below every panel (the first panel's entries), laid out, saved."""
    fig.suptitle(title, fontsize=10)
    entries = dict(zip(*reversed(axes[0].get_legend_handles_labels())))     # label -> handle
    labels = [k for k in ("route", "ground truth", *KINDS) if k in entries]
    fig.legend([entries[k] for k in labels], labels, loc="lower center", ncol=len(labels), fontsize=9,
               frameon=False, markerscale=1.6)
    height = fig.get_size_inches()[1]
    fig.tight_layout(rect=(0, 0.45 / height, 1, 1 - 0.1 / height))
    _save(fig, path)


def plot_route(path: str | os.PathLike[str], positions: Positions | None, truth: np.ndarray,
               reports: dict[str, ModeReport], title: str) -> None:
    """Each mode's answers on the route, one panel each sized to the route (its extent and a margin, equal
    scales, metres): right (green dots) and wrong (red crosses, on top) at the place answered, lost (grey
    squares) at the frame's true place where it has one; the counts of each in the panel's title. Without
    ``positions``: ``plot_progress``. One PNG, written atomically."""
    if positions is None:
        plot_progress(path, truth, reports, title)
        return
    shown = {n: r for n, r in reports.items() if r.refs is not None}
    xy = plane_xy(positions)
    (x0, x1), (y0, y1) = route_limits(xy)
    cols, rows, cw, ch = grid_layout(len(shown), (x1 - x0) / (y1 - y0))
    fig, axes = _panels(len(shown), cols, rows, (cw, ch), share=True)
    middle = truth_middle(truth)
    place = np.where(np.isnan(middle), -1, np.round(np.nan_to_num(middle, nan=-1))).astype(np.int64)
    for ax, (name, rep) in zip(axes, shown.items()):
        ax.plot(xy[:, 0], xy[:, 1], color="0.8", linewidth=3, zorder=0, label="route")
        kinds = answer_kinds(rep)
        for kind in ("right", "lost", "wrong"):      # wrong drawn last: on top
            at = place[kinds[kind] & (place >= 0)] if kind == "lost" else rep.refs[kinds[kind]]
            colour, marker = KIND_STYLE[kind]
            ax.scatter(xy[at, 0], xy[at, 1], s=30 if kind == "wrong" else 14, color=colour, marker=marker,
                       linewidths=0.3, edgecolors="white", zorder=2, label=kind)
        ax.set_title(counts_text(name, kinds, "\n"), fontsize=9)
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0, y1)
        ax.set_aspect("equal", adjustable="box")
        ax.grid(alpha=0.25)
    east, north = ("east (m)", "north (m)") if positions.geo else ("x (m)", "y (m)")
    _label_outer(axes, cols, east, north)
    _finish_grid(fig, axes, title, path)


def plot_progress(path: str | os.PathLike[str], truth: np.ndarray, reports: dict[str, ModeReport],
                  title: str) -> None:
    """Where on the route each mode puts the vehicle, frame by frame, for a map without positions: the
    reference answered (its index in the map) against the query frame, right (green dots) / wrong (red
    crosses), over the ground truth's references (pale yellow); lost frames as grey ticks along the bottom, so
    that lost stretches show as bars; the counts of each in the panel's title. One panel per mode, sharing
    axes. One PNG, written atomically."""
    shown = {n: r for n, r in reports.items() if r.refs is not None}
    cols, rows, cw, ch = grid_layout(len(shown), 1.3)
    fig, axes = _panels(len(shown), cols, rows, (cw, ch), share=True)
    tq, tk = np.nonzero(truth >= 0)
    frames = np.arange(len(truth))
    top = max([int(truth.max()) if truth.size else 0] + [int(r.refs.max()) for r in shown.values()]) + 1
    rug = -0.05 * top
    for ax, (name, rep) in zip(axes, shown.items()):
        ax.scatter(tq, truth[tq, tk], s=12, marker="s", color=TRUTH_COLOUR, linewidths=0, zorder=0,
                   label="ground truth")
        kinds = answer_kinds(rep)
        for kind in ("right", "lost", "wrong"):
            mask = kinds[kind]
            colour, marker = KIND_STYLE[kind]
            y = np.full(int(mask.sum()), rug) if kind == "lost" else rep.refs[mask]
            ax.scatter(frames[mask], y, s=40 if kind == "lost" else (28 if kind == "wrong" else 9), color=colour,
                       marker="|" if kind == "lost" else marker, linewidths=1.0 if kind == "lost" else 0.3,
                       edgecolors=None if kind == "lost" else "white", zorder=2, label=kind)
        ax.set_title(counts_text(name, kinds, "\n"), fontsize=9)
        ax.set_ylim(2 * rug, top * 1.03)
        ax.grid(alpha=0.25)
    _label_outer(axes, cols, "query frame", "reference (index in the map)")
    _finish_grid(fig, axes, title, path)
