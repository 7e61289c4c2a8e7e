"""``vpr-edge evaluate``: options in, ``evaluation.evaluate`` called, the table (and --json, --plot) out."""
from __future__ import annotations

from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING, Optional

import typer

from vpr_edge.calibration import DEFAULT_METHOD, METHODS
from vpr_edge.cli.common import (LIST_PARAMS, PARAM_HELP, PRECISION_HELP, THREADS_HELP, PrecisionOpt, app,
                                 param_options_for_all, user_errors)
from vpr_edge.errors import VprError, printable, warn
from vpr_edge.evaluation import Source, Truth, evaluate
from vpr_edge.evaluation.run import BASELINES, DEFAULT_MODES, matchers_named
from vpr_edge.features.choice import DEFAULT_PRECISION
from vpr_edge.files import atomic_output, check_not_input, check_writable, output_path
from vpr_edge.frames.images import Frame
from vpr_edge.matchers import MATCHERS
from vpr_edge.matchers.constants import TARGET_PRECISION
from vpr_edge.threads import use_threads

if TYPE_CHECKING:   # numpy is imported where the command runs
    import numpy as np


class FeaturesOpt(str, Enum):
    map = "map"
    pixels = "pixels"


FitOpt = Enum("FitOpt", {m: m for m in METHODS}, type=str)   # the calibration fits, by name


def counted_correct(truth: np.ndarray | None, tolerance: int) -> str:
    """What an answer had to be to count as correct, for the console: a reference the ground truth lists (at
    most how many it lists a query: the truth's own slack, e.g. the frame +-2) or within ``tolerance`` of one,
    which adds to that slack. ``truth``: (Q, T) the rows scored, -1 padded."""
    listed = 0 if truth is None or not truth.size else int((truth >= 0).sum(axis=1).max())
    what = f"correct: a reference the ground truth lists (up to {listed} a query)"
    return what + (f" or within {tolerance} of one" if tolerance else ", exactly")


@app.command("evaluate")
def evaluate_cmd(
    map_path: Optional[Path] = typer.Option(None, "--map", "-m", help="Map from build-map: the queries are "
                                            "encoded with its model and codebook."),
    queries: Optional[Path] = typer.Option(None, "--queries", "-q", help="Query frames: a folder (file-name "
                                           "order), a video, a ROS bag / MCAP file with --topic, or a file of "
                                           "global descriptors (.npy, .h5) for a map of them. Row i of the "
                                           "ground truth is frame i."),
    topic: Optional[str] = typer.Option(None, help="With a bag as --queries: its image topic."),
    similarity: Optional[Path] = typer.Option(None, "--similarity", help="Evaluate a (Q, R) float .npy "
                                              "similarity matrix instead (rows = queries, higher = more "
                                              "alike), e.g. from another tool's descriptors; no model needed "
                                              "(and no motion cue: mode stream then runs its stop_gain rule)."),
    refs: Optional[Path] = typer.Option(None, "--refs", help="With --features pixels: the reference folder."),
    features: FeaturesOpt = typer.Option(FeaturesOpt.map, help="map: the map's CNN features and encoding; "
                                         "pixels: SeqSLAM's front end (grey, 64x32, patch-normalised, "
                                         "mean absolute difference), from --refs and --queries, no map."),
    gt: Optional[Path] = typer.Option(None, "--gt", help="Ground truth: the project's CSV 'query,references' "
                                      "(space-separated reference indices, empty = place not in the map) or a "
                                      "boolean (Q, R) .npy matrix (VPR_Tutorial's GThard/GTsoft)."),
    gt_positions: Optional[tuple[Path, Path]] = typer.Option(
        None, "--gt-positions", help="Ground truth from positions: REFS.csv QUERIES.csv with columns x,y "
                                     "(metres) or lat,lon (degrees); see --radius. REFS may be the word map: "
                                     "the positions of the --map (built with --positions)."),
    radius: float = typer.Option(25.0, min=0.0, help="With --gt-positions: references within this many "
                                                    "metres of a query are correct."),
    modes: Optional[str] = typer.Option(None, help="Comma-separated matchers to run on the same "
                                        "similarity matrix: " + ", ".join(MATCHERS) + ". Default: "
                                        + ", ".join(DEFAULT_MODES) + " (localize's default mode, the "
                                        "probabilistic mode and the baselines); all: every one that applies "
                                        "(svm with a map built with --svm)."),
    details: bool = typer.Option(False, "--details", help="Print every column and the tables behind them "
                                 "(one view, the line, where answers fall, lost frames by why, reliability); "
                                 "default: the main columns."),
    tolerance: int = typer.Option(0, min=0, help="Frames of slack added around each reference the ground "
                                  "truth lists (default 0: the truth's own; a truth listing one frame with "
                                  "the thesis's slack: 1)."),
    window: Optional[int] = typer.Option(None, min=0, help="stream: local search window, as localize's "
                                         "(default %d; 0 = every reference every frame)."
                                         % MATCHERS["stream"].params["window"]),
    min_confidence: Optional[float] = typer.Option(None, help="Lost threshold for modes with a lost state "
                                                   "(default: each mode's own)."),
    target_precision: Optional[float] = typer.Option(
        None, help="The line of modes whose score is the probability that the answer is right (stream-filter; "
                   "default %.2f), and of every mode --calibration holds (where its drive's answers reached it); "
                   "and the precision at which every mode's best line is read." % TARGET_PRECISION),
    answers_text: Optional[str] = typer.Option(None, "--answers", help="Write each frame's answer per mode "
                                               "here (CSV: frame, mode, ref, score, probability, lost, why, "
                                               "right)."),
    param: Optional[list[str]] = typer.Option(None, "--param", metavar="KEY=VALUE",
                                              help=PARAM_HELP + " Applies to every chosen mode that has KEY."),
    list_params: bool = LIST_PARAMS,
    json_text: Optional[str] = typer.Option(None, "--json", help="Write the figures as JSON here."),
    plot_text: Optional[str] = typer.Option(None, "--plot", help="Write all modes' PR curves to this PNG "
                                            "(needs matplotlib: the plot extra)."),
    matrix_text: Optional[str] = typer.Option(None, "--plot-matrix", help="Write the similarity matrix with the "
                                              "ground truth and each mode's answers over it to this PNG (plot "
                                              "extra)."),
    route_text: Optional[str] = typer.Option(None, "--plot-route", help="Write each mode's answers, right / "
                                             "wrong / lost, to this PNG (plot extra): on the route, for a map "
                                             "built with --positions; else the reference answered against the "
                                             "frame, over the ground truth."),
    calibration_text: Optional[str] = typer.Option(None, "--save-calibration", help="Write each mode's "
                                                   "calibration here (score -> probability the answer is right, "
                                                   "on these frames' answers given; and the line at each "
                                                   "precision, over every answer), for localize "
                                                   "--calibration."),
    calibration_fit: FitOpt = typer.Option(DEFAULT_METHOD, "--calibration-fit", help="How --save-calibration "
                                           "fits: logistic (Platt scaling, two numbers; carries to another "
                                           "route better) or isotonic (a non-decreasing step curve)."),
    calibration_in: Optional[Path] = typer.Option(None, "--calibration", help="A calibration from another drive "
                                                  "or route (evaluate --save-calibration): score each mode's "
                                                  "confidence against these frames (ECE and the reliability "
                                                  "table in --json) for the modes it holds; with "
                                                  "--target-precision, their lost line is its drive's."),
    similarity_text: Optional[str] = typer.Option(None, "--save-similarity",
                                                  help="Also save the (Q, R) similarity matrix (.npy)."),
    model: Optional[Path] = typer.Option(None, help="With --map: the map's model, if not where it was."),
    batch_size: int = typer.Option(8, min=1, help="Frames per model run."),
    threads: int = typer.Option(0, min=0, help=THREADS_HELP),
    precision: PrecisionOpt = typer.Option(DEFAULT_PRECISION, help=PRECISION_HELP),
) -> None:
    """Measure matchers against ground truth, all on one similarity matrix: from --map and --queries, from
    --features pixels with --refs and --queries, or from --similarity. By default, stream beside stream-filter
    and the baselines single and seqslam-online, in a short table: R@1, AUC (thesis eq. 5.1), the shares right
    and lost, matching time; each column explained under it. --modes all runs every matcher; --details adds
    recall@5/10, AP (eq. 5.2), the median error, lock-on and exit frames and the tables behind them; --json
    holds every figure. Each file written is named on stderr."""
    import numpy as np

    from vpr_edge.evaluation import report

    with user_errors():
        # --- everything that can be checked before the work ---
        source = Source(similarity, map_path, queries, refs, features == FeaturesOpt.pixels, model, batch_size,
                        threads, topic, precision.value)
        source.check()
        truth = Truth(gt, gt_positions, radius)
        matchers = matchers_named(modes, source)
        if window is not None:
            if not any("window" in m.params for m in matchers.values()):
                warn(f"--window does not apply to modes {','.join(matchers)}; ignored")
            matchers = {n: m.with_params(window=window) if "window" in m.params else m for n, m in matchers.items()}
        if param:
            matchers = param_options_for_all(matchers, param)
        json_out, plot_out, save_similarity, matrix_out, route_out, calibration_out, answers_out = (
            output_path(t) if t else None
            for t in (json_text, plot_text, similarity_text, matrix_text, route_text, calibration_text, answers_text))
        outputs = {"--json": json_out, "--plot": plot_out, "--save-similarity": save_similarity,
                   "--plot-matrix": matrix_out, "--plot-route": route_out, "--save-calibration": calibration_out,
                   "--answers": answers_out}
        for target in outputs.values():
            if target:
                check_writable(target)
        curves = {}
        if calibration_in is not None:
            from vpr_edge import calibration as calibration_io

            curves, held = calibration_io.load_held(calibration_in, list(matchers))
            if not curves:
                raise VprError(f"{calibration_in}: no calibration for modes {','.join(matchers)} (it has "
                               f"{', '.join(held) or 'none'})")
        check_not_input(outputs, [map_path, queries, similarity, refs, gt, model, calibration_in,
                                  *(gt_positions or ())])
        drawn = [name for name, out in (("plot", plot_out), ("plot_matrix", matrix_out), ("plot_route", route_out))
                 if out]
        if drawn:
            report.require_matplotlib(*drawn)
        use_threads(threads)

        def skip(frame: Frame) -> None:
            typer.echo(f"vpr-edge: warning: {printable(frame.error)}; frame skipped (and its ground-truth row)",
                       err=True)

        result = evaluate(source, truth, matchers, tolerance, min_confidence, skip, curves, target_precision)
        sim = result.similarity
        ms = result.encode_ms
        typer.echo(f"{sim.shape[0]} queries ({result.n_mapped} of mapped places), {sim.shape[1]} references; "
                   f"{counted_correct(result.truth, tolerance)}; encoding {'-' if ms != ms else f'{ms:.1f}'} ms/frame"
                   + (f"; model {result.front['model']} ({result.front['form']})" if result.front and
                      "model" in result.front else ""))
        typer.echo(report.table(result.reports, details))
        if not details:
            typer.echo("\n--details: every column and the tables behind them; --json FILE: every figure")
        if modes is None:
            others = ", ".join(m for m in DEFAULT_MODES[1:] if m not in BASELINES)
            typer.echo(f"--modes all: every mode, not only localize's default ({DEFAULT_MODES[0]}), {others} and "
                       f"the baselines {' and '.join(BASELINES)}")

        def wrote(path: Path, what: str) -> None:
            typer.echo(f"vpr-edge: wrote {printable(str(path))} ({what})", err=True)

        if save_similarity:
            with atomic_output(save_similarity) as tmp, open(tmp, "wb") as f:
                np.save(f, sim.astype(np.float32), allow_pickle=False)
            wrote(save_similarity, f"the {sim.shape[0]} x {sim.shape[1]} similarity matrix, .npy")
        if answers_out:
            report.write_answers(answers_out, result.reports)
            wrote(answers_out, "each frame's answer per mode, CSV")
        if json_out:
            report.write_json(json_out, sim.shape[0], sim.shape[1], result.reports, tolerance, result.front)
            wrote(json_out, "the report, every figure, JSON")
        title = report.figure_title(sim.shape, map_path=map_path, queries=queries, refs=refs, similarity=similarity)
        if calibration_out:
            from vpr_edge import calibration

            curves = {n: calibration.fit(r.scores, r.correct, tolerance, ~r.lost, calibration_fit.value)
                      for n, r in result.reports.items()}
            calibration.write(calibration_out, curves, source.name, calibration_fit.value)
            target = TARGET_PRECISION if target_precision is None else target_precision
            typer.echo(f"\n{calibration_out}: with --target-precision {target:g}, each mode's line (the lowest "
                       "score whose answers at least as high these frames show right that often)")
            typer.echo("\n".join(f"  {n}: " + calibration.line_text(c, target) for n, c in curves.items()))
            wrote(calibration_out, "each mode's calibration, for localize --calibration")
        if plot_out:
            report.plot(plot_out, result.reports, title)
            wrote(plot_out, "each mode's precision-recall curve")
        if matrix_out:
            report.plot_matrix(matrix_out, sim, result.truth, result.reports, title)
            wrote(matrix_out, "the similarity matrix with each mode's answers")
        if route_out:
            report.plot_route(route_out, result.positions, result.truth, result.reports, title)
            wrote(route_out, "each mode's answers, right / wrong / lost, " + ("on the route" if result.positions
                                                                               is not None else "by frame"))
