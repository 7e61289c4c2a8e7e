"""Evaluation reports: the stdout table, the ``--json`` file, the answers' CSV, and the figures' titles; the
figures themselves (the PR curves ``--plot``, the similarity matrix with each mode's answers ``--plot-matrix``,
the route with each answer's place ``--plot-route``) are drawn in ``figures`` and named here as before."""
from __future__ import annotations

import json
import os
from collections.abc import Callable, Sequence

from vpr_edge.errors import InputError
from vpr_edge.evaluation.figures import plot, plot_matrix, plot_progress, plot_route  # noqa: F401 - drawn there
from vpr_edge.evaluation.scoring import ModeReport
from vpr_edge.matchers.base import LOST_WHY
from vpr_edge.files.atomic import atomic_output

def _cell(v: float, fmt: str = "{:.3f}") -> str:
    return "-" if v != v else fmt.format(v)


# every column of the table: name -> (its cell for a mode's report, what it means in a line)
_COLUMNS: dict[str, tuple[Callable[[ModeReport], str], str]] = {
    "R@1": (lambda r: _cell(r.recall[1]), "mapped frames whose first answer is right, lost or not"),
    "R@5": (lambda r: _cell(r.recall[5]), "mapped frames with a right answer among the first 5"),
    "R@10": (lambda r: _cell(r.recall[10]), "... among the first 10"),
    "AUC": (lambda r: _cell(r.auc), "area under the precision-recall curve, answers ranked by score"),
    "AP": (lambda r: _cell(r.ap), "average precision over the same ranking"),
    "P@R=1": (lambda r: _cell(r.precision_at_full_recall), "precision with every answer taken"),
    "R@P=1": (lambda r: _cell(r.recall_at_full_precision), "recall of the highest-scored answers before the first "
              "wrong one"),
    "med.err": (lambda r: _cell(r.median_error, "{:.1f}"), "median frames from the answer to the nearest right "
                "reference, mapped frames"),
    "lost-off": (lambda r: _cell(r.lost_unmapped), "frames of places not in the map reported lost (higher is "
                 "better)"),
    "lost-on": (lambda r: _cell(r.lost_mapped), "frames of mapped places reported lost (lower is better)"),
    "lock": (lambda r: delays_text(r.lock_frames), "frames to the first right answer on entering mapped places "
             "(start, each re-entry; never: not within)"),
    "exit": (lambda r: delays_text(r.exit_frames), "frames to report lost on leaving them"),
    "ans.ok": (lambda r: _cell(r.answered_right), "answers given (not lost) that are right: what a vehicle acting "
               "on them sees"),
    "map.ok": (lambda r: _cell(r.mapped_right), "mapped frames answered right (a lost frame is not)"),
    "ECE": (lambda r: _cell(r.ece), "how far the confidence is from the share right (a probability's, or a "
            "calibration's)"),
    "ms/frame": (lambda r: _cell(r.match_ms, "{:.2f}"), "matching time per frame, encoding apart"),
}
SHORT = ("R@1", "AUC", "ans.ok", "map.ok", "lost-off", "lost-on", "ECE", "ms/frame")   # the table without --details


def table(reports: dict[str, ModeReport], details: bool = False) -> str:
    """The console report: a fixed-width table, one row per mode, each column explained in a line under it.
    Without ``details``, the columns in ``SHORT`` (ECE only where a mode has one) and the error in metres with
    a map built with positions; with ``details``, every column, then the tables behind
    them: the shares away from where the map shows one view (with a map), the line, where the answers fall,
    lost frames by why (modes that say why) and the reliability tables (modes with a probability or a
    calibration). '-': the figure does not apply (no lost state, no such frames, no probability)."""
    shown = list(_COLUMNS) if details else [c for c in SHORT if c != "ECE"
                                            or any(r.ece == r.ece for r in reports.values())]
    width = max([len(m) for m in reports] + [4])
    lines = [f"{'mode':<{width}} " + " ".join(f"{c:>8s}" for c in shown)]
    lines += [f"{name:<{width}} " + " ".join(f"{_COLUMNS[c][0](r):>8s}" for c in shown)
              for name, r in reports.items()]
    named = max(len(c) for c in shown)
    lines += [""] + [f"  {c:<{named}}  {_COLUMNS[c][1]}" for c in shown]
    lines.append(f"  {'-':<{named}}  does not apply (no lost state, no such frames, no probability)")
    if details:
        lines += _detail_lines(reports, width)
    lines += _metre_lines(reports, width)
    return "\n".join(lines)


def _detail_lines(reports: dict[str, ModeReport], width: int) -> list[str]:
    """The tables ``--details`` adds under the main one."""
    cell = _cell
    lines: list[str] = []
    distinct = {name: r for name, r in reports.items() if r.one_view_frames >= 0}
    if distinct:
        n = next(iter(distinct.values())).one_view_frames
        lines += ["", f"away from where the map shows one view (its drive stood still or saw nothing; {n} mapped "
                      "frames' truth lies there, a count of frames no image tells apart):",
                  f"{'mode':<{width}} {'ans.ok':>8s} {'map.ok':>8s}"]
        lines += [f"{name:<{width}} {cell(r.distinct_answered_right):>8s} {cell(r.distinct_mapped_right):>8s}"
                  for name, r in distinct.items()]
    target = next(iter(reports.values())).target_precision if reports else None
    lines += ["", f"the line: the best line's recall at precision {target} (the answers ranked by score) and the line "
                  "gap (the best line's recall at the precision delivered, ans.ok, minus the recall delivered, "
                  "map.ok)", f"{'mode':<{width}} {'best@P':>8s} {'gap':>8s}"]
    lines += [f"{name:<{width}} {cell(r.best_line_recall):>8s} {cell(r.line_gap):>8s}" for name, r in reports.items()]
    lines += ["", "where the answers fall: exact = mapped frames answered at the truth's middle place; lead = the "
                  "right answers' mean frames ahead of it (+) or behind (-)",
              f"{'mode':<{width}} {'exact':>8s} {'lead':>8s}"]
    lines += [f"{name:<{width}} {cell(r.exact):>8s} {cell(r.lead, '{:+.2f}'):>8s}" for name, r in reports.items()]
    why = {name: r.lost_why for name, r in reports.items() if r.lost_why}
    if why:
        kinds = [k for k in LOST_WHY if any(k in w for w in why.values())]
        lines += ["", "lost frames by why (unmapped / mapped places): weak-view = the answer does not stand out of "
                      "what the frame sees, no-trajectory = none has built up, ambiguous = a rival along the route, "
                      "off-map = the filter holds the camera off the map, settling = its belief is still spread",
                  f"{'mode':<{width}} " + " ".join(f"{k:>11s}" for k in kinds)]
        lines += [f"{name:<{width}} " + " ".join(f"{_why_cell(w, k):>11s}" for k in kinds) for name, w in why.items()]
    return lines + reliability_lines(reports, width)


def _why_cell(why: dict[str, dict[str, int]], kind: str) -> str:
    """A lost-why cell: 'unmapped / mapped' frames lost for ``kind``, '-' where the mode never gives it."""
    return f"{why[kind]['unmapped']} / {why[kind]['mapped']}" if kind in why else "-"


def _metre_lines(reports: dict[str, ModeReport], width: int) -> list[str]:
    """The error in metres, for a map built with positions (nothing otherwise)."""
    metres = {name: r.metres for name, r in reports.items() if r.metres is not None}
    if not metres:
        return []
    keys = list(next(iter(metres.values())))
    lines = ["", "error in metres (map positions): median_m, p90_m = from the answer to the nearest right reference "
                 "(mapped frames answered); within_Xm = mapped frames answered that close",
             f"{'mode':<{width}} " + " ".join(f"{k:>10s}" for k in keys)]
    return lines + [f"{name:<{width}} " + " ".join(f"{_cell(m[k], '{:.2f}'):>10s}" for k in keys)
                    for name, m in metres.items()]


def reliability_lines(reports: dict[str, ModeReport], width: int) -> list[str]:
    """The reliability table of each mode with one (a confidence that claims a probability): per bin of
    confidence, its mean confidence, the share of those frames right and their count; the ECE under it."""
    kept = {name: r for name, r in reports.items() if r.reliability}
    if not kept:
        return []
    edges = sorted({(b["from"], b["to"]) for r in kept.values() for b in r.reliability})
    col = max(max(len(n) for n in kept), 19)
    lines = ["", "confidence against the share right: per bin of confidence, mean confidence -> share of those "
                 "frames right (frames); a calibrated confidence reads the same on both sides",
             f"{'confidence':<{width}} " + " ".join(f"{n:>{col}s}" for n in kept)]
    for lo, hi in edges:
        cells = []
        for r in kept.values():
            b = next((b for b in r.reliability if (b["from"], b["to"]) == (lo, hi)), None)
            cells.append("-" if b is None else f"{b['confidence']:.2f} -> {b['right']:.2f} ({b['n']})")
        lines.append(f"{f'{lo:.1f}-{hi:.1f}':<{width}} " + " ".join(f"{c:>{col}s}" for c in cells))
    lines.append(f"{'ECE':<{width}} " + " ".join(f"{r.ece:>{col}.3f}" for r in kept.values()))
    return lines


def delays_text(frames: Sequence[float | None]) -> str:
    """Lock-on or exit delays in frames, as the table shows them: '2/7', 'never' for NaN or None (as JSON
    holds it), '-' for none."""
    return "/".join("never" if d is None or d != d else f"{d:.0f}" for d in frames) or "-"


JSON_SCHEMA_VERSION = 9   # 2: lost shares, ms_per_frame, settings, tolerance; 3: lock/exit frames; 4: metres;
#                          5: front_end (the model file run and its form), answered_right, mapped_right, ece
#                          and reliability per mode; 6: one_view_frames, distinct_answered_right and
#                          distinct_mapped_right per mode; 7: lost_why per mode; 8: target_precision,
#                          best_line_recall and line_gap per mode; 9: exact and lead per mode


def write_json(path: str | os.PathLike[str], n_queries: int, n_refs: int, reports: dict[str, ModeReport],
               tolerance: int, front: dict | None = None) -> None:
    """``{"schema_version", "n_queries", "n_refs", "tolerance", "front_end", "modes": {MODE: {recall_at_1, ...,
    settings}}}``, written atomically; ``front_end`` (null without a map): the model file run and its form."""
    doc = {"schema_version": JSON_SCHEMA_VERSION, "n_queries": n_queries, "n_refs": n_refs,
           "tolerance": tolerance, "front_end": front, "modes": {m: r.as_json() for m, r in reports.items()}}
    with atomic_output(path) as tmp:
        tmp.write_text(json.dumps(doc, indent=1) + "\n")


ANSWER_FIELDS = ("frame", "mode", "ref", "score", "probability", "lost", "why", "right")


def write_answers(path: str | os.PathLike[str], reports: dict[str, ModeReport]) -> None:
    """Each frame's answer per mode as CSV (``ANSWER_FIELDS``; probability: that the answer is right, where
    the mode models one, else empty; why: a lost frame's reason, where the mode gives one), written
    atomically."""
    import csv

    with atomic_output(path) as tmp, open(tmp, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(ANSWER_FIELDS)
        for mode, r in reports.items():
            for i in range(len(r.refs)):
                score = float(r.scores[i])
                why = "" if r.why is None or r.why[i] is None else r.why[i]
                p = None if r.probabilities is None else float(r.probabilities[i])
                w.writerow([i, mode, int(r.refs[i]), f"{score:.6g}", "" if p is None or p != p else f"{p:.6g}",
                            int(r.lost[i]), why, int(r.correct[i])])


def require_matplotlib(*options: str) -> None:
    """Raise InputError unless matplotlib can be imported (checked before any work); the error names
    ``options``, the inputs that draw (library names: ``plot``, ``plot_matrix``, ...; default ``plot``)."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        named = options or ("plot",)
        raise InputError(", ".join(f"{{opt.{o}}}" for o in named) + (" needs" if len(named) == 1 else " need")
                         + " matplotlib: pip install 'vpr-edge[plot]'") from None


def figure_title(shape: tuple[int, int], *, map_path: str | os.PathLike[str] | None = None,
                 queries: str | os.PathLike[str] | None = None, refs: str | os.PathLike[str] | None = None,
                 similarity: str | os.PathLike[str] | None = None) -> str:
    """A figure's title: the map and the stream (or the reference folder, the similarity file) by their base
    names, never a machine's paths, and the (Q, R) ``shape``: "map m.npz, stream query (111 queries, 111
    references)"."""
    named = [f"{what} {os.path.basename(os.path.normpath(str(p)))}" for what, p in
             (("map", map_path), ("references", refs), ("stream", queries), ("similarity", similarity))
             if p is not None]
    return ", ".join(named) + f" ({shape[0]} queries, {shape[1]} references)"
