"""``vpr-edge evaluate``: options in, ``evaluation.evaluate`` called, the table (and --json, --plot) out."""
from __future__ import annotations

from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING, Optional

import typer

from vpr_edge.calibration import DEFAULT_METHOD, METHODS
from vpr_edge.cli.common import (LIST_PARAMS, PARAM_HELP, PARAMS_EPILOG, PRECISION_HELP, STANDARDISE_HELP,
                                 THREADS_HELP, PrecisionOpt, app, param_options_for_all, user_errors)
from vpr_edge.errors import VprError, printable
from vpr_edge.evaluation import Evaluation, Source, Truth, evaluate
from vpr_edge.evaluation.run import BASELINES, DEFAULT_MODES, matchers_named
from vpr_edge.encoders.standardise import STANDARDISE
from vpr_edge.features.choice import DEFAULT_PRECISION
from vpr_edge.files.atomic import atomic_output
from vpr_edge.files.checks import check_not_input, check_writable, output_path
from vpr_edge.frames.images import Frame
from vpr_edge.matchers import MATCHERS, Matcher
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


# the options, one constant each (the command's signature names them); a matcher's parameters are --param's
_MAP = typer.Option(None, "--map", "-m", help="Map from build-map: the queries are encoded with its model and "
                                              "codebook.")
_QUERIES = typer.Option(None, "--queries", "-q", help="Query frames: a folder (file-name order), a video, a ROS "
                                                      "bag / MCAP file with --topic, or a file of global descriptors "
                                                      "(.npy, .h5) for a map of them. Row i of the ground truth is "
                                                      "frame i.")
_TOPIC = typer.Option(None, help="With a bag as --queries: its image topic.")
_SIMILARITY = typer.Option(None, "--similarity", help="Evaluate a (Q, R) float .npy similarity matrix instead (rows "
                                                      "= queries, higher = more alike), e.g. from another tool's "
                                                      "descriptors; no model needed (and no motion cue: a stop is "
                                                      "then read from the similarities alone).")
_REFS = typer.Option(None, "--refs", help="With --features pixels: the reference folder.")
_FEATURES = typer.Option(FeaturesOpt.map, help="map: the map's CNN features and encoding; pixels: SeqSLAM's front "
                                               "end (grey, 64x32, patch-normalised, mean absolute difference), from "
                                               "--refs and --queries, no map.")
_GT = typer.Option(None, "--gt", help="Ground truth: the project's CSV 'query,references' (space-separated reference "
                                      "indices, empty = place not in the map) or a boolean (Q, R) .npy matrix "
                                      "(VPR_Tutorial's GThard/GTsoft).")
_GT_POSITIONS = typer.Option(None, "--gt-positions", help="Ground truth from positions: REFS.csv QUERIES.csv with "
                                                          "columns x,y (metres) or lat,lon (degrees); see --radius. "
                                                          "REFS may be the word map: the positions of the --map "
                                                          "(built with --positions).")
_RADIUS = typer.Option(25.0, min=0.0, help="With --gt-positions: references within this many metres of a query are "
                                           "correct.")
_MODES = typer.Option(None, help="Comma-separated matchers to run on the same similarity matrix: "
                                 + ", ".join(MATCHERS) + ". Default: " + ", ".join(DEFAULT_MODES)
                                 + " (localize's default mode, the probabilistic mode and the baselines); all: every "
                                 "one that applies (svm with a map built with --svm).")
_DETAILS = typer.Option(False, "--details", help="Print every column and the tables behind them (one view, the "
                                                 "line, where answers fall, lost frames by why, reliability); "
                                                 "default: the main columns.")
_TOLERANCE = typer.Option(0, min=0, help="Frames of slack added around each reference the ground truth lists "
                                         "(default 0: the truth's own; a truth listing one frame with the thesis's "
                                         "slack: 1).")
_MIN_CONFIDENCE = typer.Option(None, help="Lost threshold for modes with a lost state (default: each mode's own).")
_TARGET_PRECISION = typer.Option(
    None, help="The line of modes whose score is the probability that the answer is right (stream; "
               "default %.2f), and of every mode --calibration holds (where its drive's answers reached it); "
               "and the precision at which every mode's best line is read." % TARGET_PRECISION)
_ANSWERS = typer.Option(None, "--answers", help="Write each frame's answer per mode here (CSV: frame, mode, ref, "
                                                "score, probability, lost, why, right).")
_PARAM = typer.Option(None, "--param", metavar="KEY=VALUE",
                      help=PARAM_HELP + " Applies to every chosen mode that has KEY.")
_JSON = typer.Option(None, "--json", help="Write the figures as JSON here.")
_PLOT = typer.Option(None, "--plot", help="Write all modes' PR curves to this PNG (needs matplotlib: the plot "
                                          "extra).")
_PLOT_MATRIX = typer.Option(None, "--plot-matrix", help="Write the similarity matrix with the ground truth and each "
                                                        "mode's answers over it to this PNG (plot extra).")
_PLOT_ROUTE = typer.Option(None, "--plot-route", help="Write each mode's answers (right / wrong / lost) to this PNG "
                           "(plot extra): on the route for a map with --positions, else against the frame.")
_SAVE_CALIBRATION = typer.Option(None, "--save-calibration", help=(
    "Write each mode's calibration here, for localize --calibration: score -> probability the answer is right, "
    "fitted on these frames' answers, and the line at each precision."))
_CALIBRATION_FIT = typer.Option(DEFAULT_METHOD, "--calibration-fit", help=(
    "How --save-calibration fits: logistic (Platt scaling: carries to another route better) or isotonic."))
_CALIBRATION = typer.Option(None, "--calibration", help=(
    "A calibration from another drive (evaluate --save-calibration): each mode's confidence scored on these "
    "frames (ECE, reliability in --json); with --target-precision, its lost line is that drive's."))
_SAVE_SIMILARITY = typer.Option(None, "--save-similarity", help="Also save the (Q, R) similarity matrix (.npy).")
_MODEL = typer.Option(None, help="With --map: the map's model, if not where it was.")
_BATCH_SIZE = typer.Option(8, min=1, help="Frames per model run.")
_THREADS = typer.Option(0, min=0, help=THREADS_HELP)
_PRECISION = typer.Option(DEFAULT_PRECISION, help=PRECISION_HELP)
_STANDARDISE = typer.Option(STANDARDISE, "--standardise/--raw-cosines", help=STANDARDISE_HELP)


@app.command("evaluate", epilog=PARAMS_EPILOG)
def evaluate_cmd(map_path: Optional[Path] = _MAP, queries: Optional[Path] = _QUERIES, topic: Optional[str] = _TOPIC,
                 similarity: Optional[Path] = _SIMILARITY, refs: Optional[Path] = _REFS,
                 features: FeaturesOpt = _FEATURES, gt: Optional[Path] = _GT,
                 gt_positions: Optional[tuple[Path, Path]] = _GT_POSITIONS, radius: float = _RADIUS,
                 modes: Optional[str] = _MODES, details: bool = _DETAILS, tolerance: int = _TOLERANCE,
                 min_confidence: Optional[float] = _MIN_CONFIDENCE,
                 target_precision: Optional[float] = _TARGET_PRECISION, answers_text: Optional[str] = _ANSWERS,
                 param: Optional[list[str]] = _PARAM, list_params: bool = LIST_PARAMS,
                 json_text: Optional[str] = _JSON, plot_text: Optional[str] = _PLOT,
                 matrix_text: Optional[str] = _PLOT_MATRIX, route_text: Optional[str] = _PLOT_ROUTE,
                 calibration_text: Optional[str] = _SAVE_CALIBRATION, calibration_fit: FitOpt = _CALIBRATION_FIT,
                 calibration_in: Optional[Path] = _CALIBRATION, similarity_text: Optional[str] = _SAVE_SIMILARITY,
                 model: Optional[Path] = _MODEL, batch_size: int = _BATCH_SIZE, threads: int = _THREADS,
                 precision: PrecisionOpt = _PRECISION, standardise: bool = _STANDARDISE) -> None:
    """Measure matchers against ground truth, all on one similarity matrix: from --map and --queries, from
    --features pixels with --refs and --queries, or from --similarity. By default, stream beside the
    baselines single and seqslam-online, in a short table: R@1, AUC (thesis eq. 5.1), the shares right
    and lost, matching time; each column explained under it. --modes all runs every matcher; --details adds
    recall@5/10, AP (eq. 5.2), the median error, lock-on and exit frames and the tables behind them; --json
    holds every figure. Each file written is named on stderr."""
    with user_errors():
        # --- everything that can be checked before the work ---
        source = Source(similarity, map_path, queries, refs, features == FeaturesOpt.pixels, model, batch_size,
                        threads, topic, precision.value, standardise)
        source.check()
        truth = Truth(gt, gt_positions, radius)
        matchers = matchers_named(modes, source)
        if param:
            matchers = param_options_for_all(matchers, param)
        outputs = checked_outputs({"--json": json_text, "--plot": plot_text, "--save-similarity": similarity_text,
                                   "--plot-matrix": matrix_text, "--plot-route": route_text,
                                   "--save-calibration": calibration_text, "--answers": answers_text})
        curves = {} if calibration_in is None else held_calibration(calibration_in, matchers)
        check_not_input(outputs, [map_path, queries, similarity, refs, gt, model, calibration_in,
                                  *(gt_positions or ())])
        require_plotting(outputs)
        use_threads(threads)
        result = evaluate(source, truth, matchers, tolerance, min_confidence, _skip, curves, target_precision)
        print_table(result, tolerance, details, modes)
        write_outputs(outputs, result, tolerance, dict(map_path=map_path, queries=queries, refs=refs,
                                                       similarity=similarity), source.name, calibration_fit.value,
                      target_precision)


def checked_outputs(texts: dict[str, str | None]) -> dict[str, Path | None]:
    """Each output option's file (None: not asked for), by option, each checked writable before any work."""
    outputs = {option: output_path(text) if text else None for option, text in texts.items()}
    for target in outputs.values():
        if target:
            check_writable(target)
    return outputs


def held_calibration(path: Path, matchers: dict[str, Matcher]) -> dict:
    """The curves of calibration file ``path`` (--calibration) for the modes ``matchers`` run; VprError if it
    holds none of them."""
    from vpr_edge import calibration as calibration_io

    curves, held = calibration_io.load_held(path, list(matchers))
    if not curves:
        raise VprError(f"{path}: no calibration for modes {','.join(matchers)} (it has {', '.join(held) or 'none'})")
    return curves


def require_plotting(outputs: dict[str, Path | None]) -> None:
    """VprError before any work when a plot is asked for and matplotlib is missing."""
    from vpr_edge.evaluation import report

    drawn = [name for name, option in (("plot", "--plot"), ("plot_matrix", "--plot-matrix"),
                                       ("plot_route", "--plot-route")) if outputs[option]]
    if drawn:
        report.require_matplotlib(*drawn)


def _skip(frame: Frame) -> None:
    typer.echo(f"vpr-edge: warning: {printable(frame.error)}; frame skipped (and its ground-truth row)", err=True)


def _wrote(path: Path, what: str) -> None:
    typer.echo(f"vpr-edge: wrote {printable(str(path))} ({what})", err=True)


def print_table(result: Evaluation, tolerance: int, details: bool, modes: str | None) -> None:
    """The run's line (queries, references, what counted as correct, encoding time, model), the table and the
    hints under it (--details, --json; --modes all when the default modes ran)."""
    from vpr_edge.evaluation import report

    sim, ms = result.similarity, result.encode_ms
    typer.echo(f"{sim.shape[0]} queries ({result.n_mapped} of mapped places), {sim.shape[1]} references; "
               f"{counted_correct(result.truth, tolerance)}; encoding {'-' if ms != ms else f'{ms:.1f}'} ms/frame"
               + (f"; model {result.front['model']} ({result.front['form']})" if result.front and
                  "model" in result.front else ""))
    typer.echo(report.table(result.reports, details))
    if not details:
        typer.echo("\n--details: every column and the tables behind them; --json FILE: every figure")
    if modes is None:
        others = "".join(f"{m}, " for m in DEFAULT_MODES[1:] if m not in BASELINES)
        typer.echo(f"--modes all: every mode (stream-rules, dtw, ...), not only localize's default "
                   f"({DEFAULT_MODES[0]}), {others}the baselines {' and '.join(BASELINES)}")


def write_outputs(outputs: dict[str, Path | None], result: Evaluation, tolerance: int, named: dict,
                  source_name: str, fit: str, target_precision: float | None) -> None:
    """Write each output asked for, each named on stderr once written. ``named``: the inputs the figures'
    title names (``report.figure_title``'s keywords); ``fit``: --calibration-fit."""
    import numpy as np

    from vpr_edge.evaluation import report

    sim = result.similarity
    if outputs["--save-similarity"]:
        with atomic_output(outputs["--save-similarity"]) as tmp, open(tmp, "wb") as f:
            np.save(f, sim.astype(np.float32), allow_pickle=False)
        _wrote(outputs["--save-similarity"], f"the {sim.shape[0]} x {sim.shape[1]} similarity matrix, .npy")
    if outputs["--answers"]:
        report.write_answers(outputs["--answers"], result.reports)
        _wrote(outputs["--answers"], "each frame's answer per mode, CSV")
    if outputs["--json"]:
        report.write_json(outputs["--json"], sim.shape[0], sim.shape[1], result.reports, tolerance, result.front)
        _wrote(outputs["--json"], "the report, every figure, JSON")
    title = report.figure_title(sim.shape, **named)
    if outputs["--save-calibration"]:
        save_calibration(outputs["--save-calibration"], result, tolerance, source_name, fit, target_precision)
    if outputs["--plot"]:
        report.plot(outputs["--plot"], result.reports, title)
        _wrote(outputs["--plot"], "each mode's precision-recall curve")
    if outputs["--plot-matrix"]:
        report.plot_matrix(outputs["--plot-matrix"], sim, result.truth, result.reports, title)
        _wrote(outputs["--plot-matrix"], "the similarity matrix with each mode's answers")
    if outputs["--plot-route"]:
        report.plot_route(outputs["--plot-route"], result.positions, result.truth, result.reports, title)
        _wrote(outputs["--plot-route"], "each mode's answers, right / wrong / lost, "
               + ("on the route" if result.positions is not None else "by frame"))


def save_calibration(path: Path, result: Evaluation, tolerance: int, source_name: str, fit: str,
                     target_precision: float | None) -> None:
    """--save-calibration: each mode's curve fitted on these answers, written to ``path``; each mode's line at
    the target precision printed."""
    from vpr_edge import calibration

    curves = {n: calibration.fit(r.scores, r.correct, tolerance, ~r.lost, fit) for n, r in result.reports.items()}
    calibration.write(path, curves, source_name, fit)
    target = TARGET_PRECISION if target_precision is None else target_precision
    typer.echo(f"\n{path}: with --target-precision {target:g}, each mode's line (the lowest score whose answers at "
               "least as high these frames show right that often)")
    typer.echo("\n".join(f"  {n}: " + calibration.line_text(c, target) for n, c in curves.items()))
    _wrote(path, "each mode's calibration, for localize --calibration")
