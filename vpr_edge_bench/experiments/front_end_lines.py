"""The lost line on many front ends, scored from the similarity matrices front-end-cache wrote.

The lost line on many front ends (docs/results.md, "The line on any front end"): each stream mode's answers
on every derived stream and on foreign imagery, from the similarity matrices the ``front-end-cache`` experiment
wrote, scored by the library's ``scoring.evaluate_mode`` (what ``evaluate`` runs). ``--frames twice`` or
``drop:P`` replays each stream as a camera that repeats or loses frames (``frame_edits``).

    python -m vpr_edge_bench front-end-cache --streams out/corridor out/nordland-dev --out out/fronts
    python -m vpr_edge_bench front-end-lines --cache out/fronts --modes stream,stream-rules,seqslam-online

Per dataset and front end, one row per mode and stream: the front end alone (``single``'s R@1 at the cache's
tolerance), the best answers' R@1 (lost ignored), the precision
and recall the line delivers (answered right, mapped right; distinct: over the frames whose truth is not where
the map shows one view), the best line's recall at the target precision
(the answers ranked by score), the line gap (the best line's recall at the delivered precision minus the
delivered recall), and on the detour the unmapped frames lost and the first lost after leaving; foreign
imagery (the other dataset's aligned frames against this map): the share of frames lost. Tolerance 2 (the
derived streams' truth names one place). Then the same as ranges over the derived streams, one row per
dataset, front end and mode (docs/tables.md's table), and per dataset and mode the streams that meet each
target of the line (``targets``): a line gap of at most ``GAP``; where the front end allows the target
(*eligible*: the best line reaches it with at least half of the best answers' R@1), a precision of answers
at least the target, over every frame and over the frames whose truth is not where the map shows one view
(a stop of the mapping drive: its references alike, the truth's one of them by convention); not silent (mapped
right at least half the best answers' R@1) on the eligible streams and, apart, on the streams the matcher
follows (best answers' R@1 at least ``FOLLOWED``) that are not eligible: there no line on the mode's score
answers half at the target precision, so not silent means answers below it; the detour's unmapped frames and
foreign imagery lost for at least ``UNMAPPED_LOST`` and ``FOREIGN_LOST``. Last, for the modes whose score is a
probability (``stream``), its reliability (``reliability``): per bin of the probability,
the share of answers right, over the derived streams' frames but those whose truth lies where the map shows one
view (foreign imagery: its own column), per front end and pooled; beside it each front end's lead, the median
of how far ahead of the truth the frame's best match within ``LEAD_REACH`` of it lies (the truth's convention
against what the front end sees).

With ``--oracle``, last, per dataset and mode the targets met when each front end's line is the one score
that meets the most of them (``best_line``: chosen with the truth, so not a line a vehicle can draw; what the
mode's ranking allows, apart from where its line sits).

With ``--calibrate-on STREAM`` each front end's and mode's calibration is fitted on that stream, a labelled
drive (``evaluate --save-calibration``: ``calibration.fit``), and every other stream is lost below the line
where that drive's answers showed the target precision (``localize --calibration FILE --target-precision P``);
the reliability table is left out (the probability does not depend on the line).

With ``--half first|second|both`` every stream and foreign imagery is scored against that half of the map's
references alone (``route_halves.cut_stream``: the frames whose truth lies there, a detour's unmapped run
between them kept), and ``--calibrate-on``'s drive is cut to the other half: the labelled drive and the streams
then share no place and no image (``both``: each half in turn). ``--counts`` prints the targets' counts only.
"""
from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vpr_edge import calibration
from vpr_edge.calibration import Curve
from vpr_edge.errors import VprError
from vpr_edge.evaluation.scoring import ModeReport, evaluate_mode
from vpr_edge.matchers import get_matcher
from vpr_edge.matchers.constants import TARGET_PRECISION
from vpr_edge.threads import use_threads
from vpr_edge_bench import frame_edits
from vpr_edge_bench.line_targets import (EDGES, LEAD_REACH, StreamAnswers, StreamFigures, best_line,
                                         count_text, lead, line_figures, reliability, targets)
from vpr_edge_bench.route_halves import HALVES, MIN_FRAMES, cut_stream, half_bounds, other_half
from vpr_edge_bench.runner import parser, run_checked


def load(path: Path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def matcher_of(mode: str):
    """A mode as ``--modes`` names it: a registered matcher, or ``NAME:KEY=VALUE[;KEY=VALUE]`` with some of its
    parameters set (``Matcher.parse_params``, as ``--param`` reads them), e.g. ``stream:stuck=0``."""
    name, _, spec = mode.partition(":")
    m = get_matcher(name)
    return m.with_params(**m.parse_params(spec.split(";"))) if spec else m


def score(mode: str, case: dict[str, np.ndarray], tolerance: int, target: float, curve: Curve | None = None):
    """``mode``'s report on one cached stream (``evaluate_mode``); with a calibration ``curve``, lost below its
    drive's line at ``target`` (as ``localize --calibration --target-precision`` draws it)."""
    m = matcher_of(mode)
    if m.reads_route and "route" in case:
        m = dataclasses.replace(m, route=case["route"].astype(bool), reach=int(case["reach"]))
    still = case.get("cue")
    return evaluate_mode(m, case["sim"], case["truth"], tolerance, still=still, calibration=curve,
                         one_view=case.get("one_view"), target_precision=target)


def main(argv: Sequence[str] | None = None) -> int:
    p = parser(__name__, __doc__)
    p.add_argument("--cache", type=Path, required=True)
    p.add_argument("--modes", default="stream,stream-rules,seqslam-online",
                   help="comma-separated modes, each a registered matcher or NAME:KEY=VALUE[;KEY=VALUE] "
                        "(some of its parameters set, e.g. stream:stuck=0)")
    p.add_argument("--fronts", default=None, help="comma-separated front ends (default: every one cached)")
    p.add_argument("--tolerance", type=int, default=2)
    p.add_argument("--target-precision", type=float, default=TARGET_PRECISION)
    p.add_argument("--ranges", action="store_true", help="print the ranges over the streams only (docs/tables.md)")
    p.add_argument("--oracle", action="store_true",
                   help="also the one line per dataset, front end and mode that meets the most targets at once, "
                        "chosen with the truth: what the mode's ranking allows")
    p.add_argument("--calibrate-on", default=None, metavar="STREAM",
                   help="fit each front end's and mode's calibration on this derived stream (a labelled drive: "
                        "evaluate --save-calibration) and draw every other stream's line where that drive's "
                        "answers reached the target precision (localize --calibration --target-precision); the "
                        "stream itself is left out of the figures")
    p.add_argument("--half", choices=(*HALVES, "both"), default=None,
                   help="score every stream against this half of the map's references only (both: each half in "
                        "turn), and fit --calibrate-on's drive on the other half (no place nor image shared)")
    p.add_argument("--counts", action="store_true",
                   help="print the streams that meet each target only (no rows, ranges nor reliability)")
    p.add_argument("--frames", default="as-recorded", metavar="EDIT",
                   help="as-recorded; twice (every frame twice, bit for bit: a video whose frame rate was raised "
                        "by repeating frames); drop:P (each frame after the first lost with probability P)")
    p.add_argument("--seed", type=int, default=0, help="the seed of --frames drop:P")
    a = p.parse_args(argv)
    return run_checked(__name__, lambda: _run(a))


def cases(files: Sequence[Path], half: str | None) -> list[tuple[str, dict[str, np.ndarray]]]:
    """Each cached stream's name and arrays (the map's file left out), cut to ``half`` of the map where given
    (streams with too few frames there left out)."""
    out = []
    for f in files:
        case = load(f)
        if "sim" not in case:   # the map, the noise drawn
            continue
        if half is not None:
            cut = cut_stream(case, *half_bounds(case["sim"].shape[1], half))
            if cut is None:
                continue
            case = cut
        out.append((f.stem, case))
    return out


def check_cache(cache: Path, modes: str) -> None:
    """VprError unless ``cache`` is a folder and each of the comma-separated ``modes`` names a matcher (with
    parameters it has): checked before the work."""
    if not cache.is_dir():
        raise VprError(f"{cache}: not a folder (front-end-cache writes it)")
    try:
        for mode in modes.split(","):
            matcher_of(mode)
    except ValueError as e:
        raise VprError(f"--modes: {e}") from None


def _run(a: argparse.Namespace) -> int:
    """The work of ``main``, the cache and the modes checked first."""
    check_cache(a.cache, a.modes)
    try:
        frame_edits.parse(a.frames)
    except ValueError as e:
        raise VprError(str(e)) from None
    datasets = sorted(d for d in a.cache.iterdir() if d.is_dir() and d.name != "models")
    fronts_of = {ds: [f for f in sorted(g.name for g in ds.iterdir() if g.is_dir())
                      if not a.fronts or f in a.fronts.split(",")] for ds in datasets}
    halves: list[str | None] = [None] if a.half is None else list(HALVES) if a.half == "both" else [a.half]
    if a.calibrate_on:   # every front end's labelled drive, before the work
        for ds, fronts in fronts_of.items():
            for front in fronts:
                drive = ds / front / f"{a.calibrate_on}.npz"
                if not drive.is_file():
                    raise VprError(f"{drive}: no such stream to calibrate on (--calibrate-on)")
                for half in halves:
                    if half and not cases([drive], other_half(half)):
                        raise VprError(f"{drive}: fewer than {MIN_FRAMES} frames on the {other_half(half)} half "
                                       "of the map to calibrate on (--half)")
    use_threads(2)
    for half in halves:
        _score_all(a, fronts_of, half)
    return 0


def _score_all(a: argparse.Namespace, fronts_of: dict[Path, list[str]], half: str | None) -> None:
    """Every mode on every cached stream of ``fronts_of`` (dataset folder -> its front ends), against ``half``
    of the map (None: all of it); prints what ``main``'s options ask."""
    modes = a.modes.split(",")
    if half:
        print(f"\nevery stream against the {half} half of the map's references")
    if a.calibrate_on:
        where = f" on the {other_half(half)} half of the map" if half else ""
        print(f"each line from a calibration on {a.calibrate_on}{where} (left out below)")
    seen: dict[tuple[str, str, str], list[StreamFigures]] = {}   # (dataset, front, mode) -> each stream's
    sure: dict[tuple[str, str, str], list[tuple[np.ndarray, np.ndarray]]] = {}   # ... (probability, right) per stream
    leads: dict[tuple[str, str], list[np.ndarray]] = {}   # (dataset, front) -> each stream's leads
    answers: dict[tuple[str, str, str], list[StreamAnswers]] = {}   # ... each stream's answers (--oracle)
    frames = "" if a.frames == "as-recorded" else f", frames {a.frames}"
    frames += f" (seed {a.seed})" if a.frames.startswith("drop") else ""
    print(f"tolerance {a.tolerance}, target precision {a.target_precision}{frames}")
    row = (lambda text: None) if a.ranges or a.counts else (lambda text: print(text, flush=True))   # per stream
    row("| dataset | front end | mode | stream | single R@1 | best R@1 | answered right | mapped right | "
        "distinct mapped right | best line @P | line gap | unmapped lost (first) | exact | signed error |")
    row("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for ds, fronts in fronts_of.items():
        for front in fronts:
            drive = ds / front / f"{a.calibrate_on}.npz" if a.calibrate_on else None
            files = [f for f in sorted((ds / front).glob("*.npz")) if f != drive]
            for mode in modes:
                curve = None if drive is None else drive_curve(mode, drive, half, a.tolerance, a.target_precision)
                for stem, case in cases(files, half):
                    case = frame_edits.edited(case, a.frames, a.seed)
                    r = score(mode, case, a.tolerance, a.target_precision, curve)
                    key = (ds.name, front, mode)
                    if r.probability and stem != "foreign":   # frames whose truth is not at one view
                        keep = np.ones(len(r.correct), bool) if r.one_view is None else ~r.one_view
                        sure.setdefault(key, []).append((r.probabilities[keep], r.correct[keep]))
                    if mode == modes[0] and stem != "foreign":
                        leads.setdefault((ds.name, front), []).append(lead(case["sim"], case["truth"]))
                    if a.oracle and r.scores is not None:
                        answers.setdefault(key, []).append(stream_answers(r, stem, case))
                    fig = stream_figures(r, stem, case)
                    row(figures_row(key, fig, r))
                    seen.setdefault(key, []).append(fig)
    if not a.counts:
        print_ranges(seen)
    print_targets(seen, a.target_precision)
    if not a.calibrate_on and not a.counts:   # the probability is the same whatever the line: once, without a drive
        print_reliability(sure, leads)
    if a.oracle:
        print_oracle(answers, a.target_precision)


def drive_curve(mode: str, drive: Path, half: str | None, tolerance: int, target: float) -> Curve:
    """``mode``'s calibration on the labelled ``drive`` (cut to the other half of the map than ``half``, where
    given): every answer's score and rightness, the answers given (``evaluate --save-calibration``)."""
    labelled = cases([drive], half and other_half(half))[0][1]   # checked in _run
    fit = score(mode, labelled, tolerance, target)
    return calibration.fit(fit.scores, fit.correct, tolerance, ~fit.lost)


def stream_figures(r: ModeReport, stem: str, case: dict[str, np.ndarray]) -> StreamFigures:
    """One mode's report on the cached stream ``stem`` as the figures the tables count (foreign imagery: its
    share lost only; the detour: its unmapped frames lost too)."""
    nan = float("nan")
    if stem == "foreign":
        return StreamFigures(nan, nan, nan, nan, nan, nan, r.lost_unmapped, stem)
    return StreamFigures(r.recall[1], r.answered_right, r.distinct_answered_right, r.mapped_right,
                         r.best_line_recall, r.line_gap, r.lost_unmapped if stem == "detour" else nan, stem,
                         float(case.get("single_r1_tol", nan)), r.exit_frames[0] if r.exit_frames else None,
                         r.exact, r.lead)


def stream_answers(r: ModeReport, stem: str, case: dict[str, np.ndarray]) -> StreamAnswers:
    """One mode's answers on the cached stream ``stem``, for lines drawn afresh (``--oracle``)."""
    view = np.zeros(len(r.correct), bool) if r.one_view is None else r.one_view
    return StreamAnswers(stem, r.scores, r.correct, (case["truth"] >= 0).any(axis=1), view,
                         r.recall[1] if stem != "foreign" else float("nan"), r.best_line_recall)


def figures_row(key: tuple[str, str, str], fig: StreamFigures, r: ModeReport) -> str:
    """The per-stream table's row of ``fig`` (``r``'s figures) for (dataset, front end, mode) ``key``."""
    ds, front, mode = key
    if fig.stream == "foreign":
        return f"| {ds} | {front} | {mode} | foreign | - | - | - | - | - | - | - | {r.lost_unmapped:.3f} | - | - |"
    distinct = "-" if np.isnan(r.distinct_mapped_right) else f"{r.distinct_mapped_right:.3f}"
    return (f"| {ds} | {front} | {mode} | {fig.stream} | {fig.single:.3f} | {r.recall[1]:.3f} | "
            f"{r.answered_right:.3f} | {r.mapped_right:.3f} | {distinct} | {r.best_line_recall:.3f} | "
            f"{r.line_gap:.3f} | "
            f"{unmapped(r.lost_unmapped, fig.first_exit)} | {r.exact:.3f} | {r.lead:+.2f} |")


def print_oracle(answers: dict[tuple[str, str, str], list[StreamAnswers]], target: float) -> None:
    """Per dataset and mode, the streams of every front end that meet each target with each front end's
    ``best_line`` (chosen with the truth), then those lines."""
    seen: dict[tuple[str, str, str], list[StreamFigures]] = {}   # each stream's figures at its front end's line
    lines: dict[tuple[str, str], dict[str, float]] = {}   # (dataset, mode) -> front end -> its line
    for (ds, front, mode), streams in answers.items():
        line, _ = best_line(streams, target)
        lines.setdefault((ds, mode), {})[front] = line
        seen[(ds, front, mode)] = [line_figures(s, line) for s in streams]
    rows = pooled_targets(seen, target)
    names = list(next(iter(rows.values())))
    print("\none line per dataset, front end and mode, chosen with the truth (the most targets met at once): "
          "streams that meet each target")
    print("\n| dataset | mode | " + " | ".join(names) + " |")
    print("|---|---|" + "---|" * len(names))
    for (ds, mode), row in rows.items():
        print(f"| {ds} | `{mode}` | " + " | ".join(row.get(n, "-") for n in names) + " |")
    fronts = sorted({f for per in lines.values() for f in per})
    print("\nthose lines (scores; inf: no answer)\n\n| dataset | mode | " + " | ".join(fronts) + " |")
    print("|---|---|" + "---|" * len(fronts))
    for (ds, mode), per in lines.items():
        print(f"| {ds} | `{mode}` | " + " | ".join(f"{per[f]:.3f}" if f in per else "-" for f in fronts) + " |")


def unmapped(lost: float, first_exit: float | None) -> str:
    """The share of unmapped frames lost and, in brackets, the frames until the first ("-": none unmapped)."""
    if np.isnan(lost):
        return "-"
    return f"{lost:.3f}" + ("" if first_exit is None else f" ({first_exit:.0f})")


def pooled_targets(seen: dict[tuple[str, str, str], list[StreamFigures]],
                   target: float) -> dict[tuple[str, str], dict[str, str]]:
    """Per dataset and mode, ``targets`` ("met/of") over the streams of every front end (``seen``: (dataset, front end,
    mode) -> each stream's figures, foreign imagery among them)."""
    streams: dict[tuple[str, str], list[StreamFigures]] = {}   # (dataset, mode) -> every front end's streams
    foreign: dict[tuple[str, str], list[float]] = {}          # (dataset, mode) -> each front end's foreign lost
    for (ds, _, mode), figs in seen.items():
        streams.setdefault((ds, mode), []).extend(f for f in figs if f.stream != "foreign")
        foreign.setdefault((ds, mode), []).extend(f.unmapped_lost for f in figs if f.stream == "foreign")
    return {key: count_text(targets(figs, foreign[key] or None, target)) for key, figs in streams.items()}


def print_targets(seen: dict[tuple[str, str, str], list[StreamFigures]], target: float) -> None:
    """Per dataset and mode, the streams of every front end that meet each target of the line (``targets``)."""
    rows = pooled_targets(seen, target)
    if not rows:
        return
    names = list(next(iter(rows.values())))
    print("\nstreams (every front end) that meet each target, tolerance as above, target precision", target)
    print("\n| dataset | mode | " + " | ".join(names) + " |")
    print("|---|---|" + "---|" * len(names))
    for (ds, mode), row in rows.items():
        print(f"| {ds} | `{mode}` | " + " | ".join(row.get(n, "-") for n in names) + " |")


def print_reliability(sure: dict[tuple[str, str, str], list[tuple[np.ndarray, np.ndarray]]],
                      leads: dict[tuple[str, str], list[np.ndarray]]) -> None:
    """Per dataset, probability mode and front end (and pooled over the front ends): the share of answers right
    per bin of the probability (``reliability``), with the front end's median lead (``lead``)."""
    if not sure:
        return
    bins = [f"p {lo:.2f}-{hi:.2f}" for lo, hi in zip(EDGES[:-1], EDGES[1:])]
    print("\nthe probability's reliability on the derived streams: share of answers right (answers) per bin, frames "
          "whose truth lies where the map shows one view left out; lead: the median of how far ahead of the truth "
          f"each frame's best match within {LEAD_REACH} lies")
    print("\n| dataset | mode | front end | lead | " + " | ".join(bins) + " |")
    print("|---|---|---|---|" + "---|" * len(bins))

    def cells(parts: list[tuple[np.ndarray, np.ndarray]]) -> str:
        table = reliability(np.concatenate([p for p, _ in parts]), np.concatenate([r for _, r in parts]))
        return " | ".join("-" if n == 0 else f"{share:.2f} ({n})" for share, n in table)

    pooled: dict[tuple[str, str], list[tuple[np.ndarray, np.ndarray]]] = {}
    for (ds, front, mode), parts in sure.items():
        pooled.setdefault((ds, mode), []).extend(parts)
        ahead = np.concatenate(leads.get((ds, front), [np.zeros(0)]))
        median = f"{np.median(ahead):+.0f}" if len(ahead) else "-"
        print(f"| {ds} | `{mode}` | {front} | {median} | {cells(parts)} |")
    for (ds, mode), parts in pooled.items():
        print(f"| {ds} | `{mode}` | every one | | {cells(parts)} |")


def print_ranges(seen: dict[tuple[str, str, str], list[StreamFigures]]) -> None:
    """Per dataset, front end and mode: each figure's range over the derived streams, the detour's unmapped
    frames lost (first lost after leaving) and foreign imagery lost."""
    def span(values: list[float]) -> str:
        v = [x for x in values if not np.isnan(x)]
        return f"{min(v):.2f}-{max(v):.2f}" if v else "-"

    def signed(values: list[float]) -> str:
        v = [x for x in values if not np.isnan(x)]
        return f"{min(v):+.2f} to {max(v):+.2f}" if v else "-"
    print("\n| dataset | front end | mode | single R@1 | best R@1 | answered right | mapped right | "
          "best line @P | line gap | detour unmapped lost (first) | foreign lost | exact | signed error |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for (ds, front, mode), figs in seen.items():
        streams = [f for f in figs if f.stream != "foreign"]
        foreign = next((f"{f.unmapped_lost:.3f}" for f in figs if f.stream == "foreign"), "-")
        detour = next((unmapped(f.unmapped_lost, f.first_exit) for f in streams if f.stream == "detour"), "-")
        cols = [span([getattr(f, k) for f in streams])
                for k in ("single", "best_r1", "answered_right", "mapped_right", "best_line", "line_gap")]
        print(f"| {ds} | {front} | `{mode}` | " + " | ".join(cols) + f" | {detour} | {foreign} | "
              f"{span([f.exact for f in streams])} | {signed([f.lead for f in streams])} |")
