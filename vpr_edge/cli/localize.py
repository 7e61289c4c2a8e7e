"""``vpr-edge localize``: options in, ``api.Localizer.run`` over the stream, one result line per frame out."""
from __future__ import annotations

import sys
import time
from enum import Enum
from pathlib import Path
from typing import Optional

import typer

from vpr_edge.api import Localizer
from vpr_edge.cli.common import (LIST_PARAMS, MODE_HELP, PARAM_HELP, PARAMS_EPILOG, PRECISION_HELP, STANDARDISE_HELP,
                                 THREADS_HELP, ModeOpt, PrecisionOpt, app, user_errors)
from vpr_edge.errors import Terminated, VprError, ctrl_c, held_signals, printable
from vpr_edge.encoders.standardise import STANDARDISE
from vpr_edge.features.choice import DEFAULT_PRECISION
from vpr_edge.files.checks import check_not_input, check_writable, output_path
from vpr_edge.frames.images import Frame, GreyFrames, open_stream
from vpr_edge.frames.limits import Limited
from vpr_edge.matchers import DEFAULT_MATCHER, MATCHERS, get_matcher
from vpr_edge.matchers.constants import TARGET_PRECISION
from vpr_edge.outputs.sink import ResultSink
from vpr_edge.outputs.log import SUFFIX_FORMATS, ResultLog, writing
from vpr_edge.outputs.live import check_live, is_mcap, live_sinks
from vpr_edge.outputs.summary import RunSummary, reference_size


class FormatOpt(str, Enum):
    csv = "csv"
    jsonl = "jsonl"


# the options, one constant each (the command's signature names them); a matcher's parameters are --param's
_MAP = typer.Option(..., "--map", "-m", help="Map file written by build-map.")
_STREAM = typer.Option(..., "--stream", "-s", metavar="SOURCE",
                       help="Folder of frames (file-name order), a video file, a camera (0, 1, ... or /dev/video0), "
                            "a network stream (rtsp://...), a ROS bag (--topic), or for a map of descriptors a file "
                            "of them (.npy rows, hloc .h5).")
_MODEL = typer.Option(None, help="ONNX feature model; must be the map's model (default: $VPR_EDGE_MODEL if set, "
                                 "else the file the map was built with if it still exists, else the bundled one).")
_MODE = typer.Option(DEFAULT_MATCHER, metavar="MATCHER", help=MODE_HELP)
_MIN_CONFIDENCE = typer.Option(
    None, help="Frames scoring below this are reported lost (reference and position fields empty). "
               "Default: the mode's own (stream: its --target-precision; stream-rules: %.1f; other modes: never lost)."
               % MATCHERS["stream-rules"].min_confidence)
_TARGET_PRECISION = typer.Option(
    None, help="Modes whose score is the probability that the answer is right (stream): the line, "
               "answers below it are lost (default %.2f). With --calibration, any mode: the line where the "
               "labelled drive's answers at least as sure were right this often; else refused for another "
               "mode (stream-rules: its line is --min-confidence)." % TARGET_PRECISION)
_PARAM = typer.Option(None, "--param", metavar="KEY=VALUE", help=PARAM_HELP)
_CALIBRATION = typer.Option(None, help="A calibration (evaluate --save-calibration on a labelled drive of this "
                                       "route): each line's confidence is then the probability that its answer is "
                                       "right.")
_OUT = typer.Option(None, "--out", "-o", help="Write results here instead of stdout: lines go to NAME.part as "
                                              "frames are matched, renamed NAME when the stream ends however it "
                                              "ends (Ctrl-C, SIGTERM, a limit, a failure: every line written is "
                                              "kept); never over an input; a symbolic link is written through.")
_VIEW = typer.Option(False, "--view", help="Show the stream in a Rerun Viewer as it is matched: the frame beside "
                                           "the matched reference, where on the route, score, confidence and lost "
                                           "stretches (view extra; one already on port 9876 is used, else one is "
                                           "started with its usage analytics off).")
_RERUN = typer.Option(None, "--rerun", metavar="FILE.rrd", help="Record what --view shows to this Rerun file "
                                                                "(view extra; renamed into place when the stream "
                                                                "ends).")
_MAX_FRAMES = typer.Option(None, "--max-frames", min=1, metavar="N",
                           help="Stop after N frames read from the stream (exit 0).")
_DURATION = typer.Option(None, min=0.001, metavar="SECONDS",
                         help="Stop reading frames this many seconds after the stream starts (exit 0).")
_FORMAT = typer.Option(None, "--format", help="csv or jsonl (default: from --out's suffix, csv on stdout).")
_TOPIC = typer.Option(None, help="With a ROS 1/2 bag or MCAP file: the image topic (sensor_msgs/Image or "
                                 "CompressedImage; frames stamped by their headers).")
_TIMESTAMPS = typer.Option(None, help="With a folder of frames: a CSV frame,stamp giving each frame's time in "
                                      "seconds (videos and live sources are stamped by themselves).")
_BATCH_SIZE = typer.Option(1, min=1, help="Frames per model run (1 = lowest latency).")
_THREADS = typer.Option(0, min=0, help=THREADS_HELP)
_PRECISION = typer.Option(DEFAULT_PRECISION, help=PRECISION_HELP)
_STANDARDISE = typer.Option(STANDARDISE, "--standardise/--raw-cosines", help=STANDARDISE_HELP)


@app.command("localize", epilog=PARAMS_EPILOG)
def localize_cmd(map_path: Path = _MAP, stream: str = _STREAM, model: Optional[Path] = _MODEL, mode: ModeOpt = _MODE,
                 min_confidence: Optional[float] = _MIN_CONFIDENCE,
                 target_precision: Optional[float] = _TARGET_PRECISION, param: Optional[list[str]] = _PARAM,
                 calibration: Optional[Path] = _CALIBRATION, list_params: bool = LIST_PARAMS,
                 out_text: Optional[str] = _OUT, view: bool = _VIEW, rerun_text: Optional[str] = _RERUN,
                 max_frames: Optional[int] = _MAX_FRAMES, duration: Optional[float] = _DURATION,
                 fmt: Optional[FormatOpt] = _FORMAT, topic: Optional[str] = _TOPIC,
                 timestamps: Optional[Path] = _TIMESTAMPS, batch_size: int = _BATCH_SIZE, threads: int = _THREADS,
                 precision: PrecisionOpt = _PRECISION, standardise: bool = _STANDARDISE) -> None:
    """Localise every frame of a stream against a map. One line per frame: frame index, name and time
    (seconds), the matched reference's index and name, its position (x,y or lat,lon, heading, metres along
    the route) when the map has positions, score (higher = more confident) and lost (0/1); the reference and
    position fields are empty when lost. Undecodable frames are reported on stderr and skipped. When the
    stream ends (its end, a limit, Ctrl-C, SIGTERM, a failure) every line written is kept and a summary goes
    to stderr (docs/usage.md, On the vehicle)."""
    with user_errors():
        inputs = [map_path, stream, model, timestamps, calibration]
        out, record, form = checked_outputs(out_text, fmt.value if fmt else None, rerun_text, view, inputs)
        params = get_matcher(mode.value).parse_params(param or [])
        frames, count = open_stream(stream, timestamps, topic)
        localizer = Localizer(map_path, model=model, mode=mode.value, params=params,
                              min_confidence=min_confidence, threads=threads, calibration=calibration,
                              precision=precision.value, target_precision=target_precision,
                              standardise=standardise)
        localizer.query.check_source(stream)   # descriptors for a map of descriptors, images for one of images
        say_choices(localizer, calibration, target_precision, precision.value)
        folder = stream if Path(stream).is_dir() else None   # a folder's frames named by their paths
        limited = Limited(GreyFrames.of(localizer.query.front).watch(frames, folder), max_frames, duration)
        if max_frames is not None and count is not None:
            count = min(count, max_frames)
        sinks, log = result_sinks(localizer, map_path, stream, out, form, view, record)
        run_stream(localizer, limited, sinks, log, RunSummary(reference_size(localizer.map.meta)), batch_size,
                   count, stream)


def checked_outputs(out_text: str | None, fmt: str | None, rerun_text: str | None, view: bool,
                    inputs: list) -> tuple[Path | None, Path | None, str]:
    """--out and --rerun checked before any work: writable, none of ``inputs``, --format (``fmt``) agreeing with
    --out's suffix, the extras --view and --rerun need; standard output, when the lines go there, open. Returns
    (out, record, the lines' format: csv or jsonl)."""
    out = output_path(out_text) if out_text else None
    if out:
        check_writable(out)
        check_not_input({"--out": out}, inputs)
    else:
        with writing("stdout"):
            sys.stdout.write("")      # a closed standard output fails here, before any work
    suffix_fmt = SUFFIX_FORMATS.get(out.suffix.lower()) if out else None
    if fmt and suffix_fmt and fmt != suffix_fmt:
        raise VprError(f"{out}: --format {fmt} contradicts the file's {out.suffix} suffix")
    record = output_path(rerun_text) if rerun_text else None
    check_live(out, fmt, view, record)     # the extras, before the work
    if record is not None:
        check_writable(record)
        check_not_input({"--rerun": record}, inputs)
    return out, record, fmt or suffix_fmt or "csv"


def say_choices(localizer: Localizer, calibration: Path | None, target_precision: float | None,
                precision: str) -> None:
    """On stderr, once: the lost line a calibration's labelled drive set, and what --precision auto chose."""
    if localizer.drive_line:   # the line in force, from the labelled drive
        typer.echo(f"vpr-edge: lost below score {localizer.threshold:.6g}: where {calibration}'s labelled drive "
                   f"shows precision {target_precision:g}", err=True)
    if precision == "auto" and "form" in localizer.front_description:   # what auto chose, said once
        typer.echo(f"vpr-edge: --precision auto: {localizer.front_description['model']} "
                   f"({localizer.front_description['form']})", err=True)


def result_sinks(localizer: Localizer, map_path: Path, stream: str, out: Path | None, form: str, view: bool,
                 record: Path | None) -> tuple[list[ResultSink], ResultLog | None]:
    """Every output of the stream (the result log, unless --out is an MCAP file, then the live ones), each to get
    every answer, then close(); and the result log."""
    sinks: list[ResultSink] = live_sinks(localizer, map_path, stream, out, view, record)
    log = None if is_mcap(out) else ResultLog(form, out)
    return ([log] if log else []) + sinks, log


def _said(text: str) -> None:
    """A line on stderr, ``vpr-edge: text``, on a line of its own (off the progress bar)."""
    typer.echo(f"vpr-edge: {printable(text)}", err=True)


def _ended_by(e: BaseException) -> str:
    if isinstance(e, KeyboardInterrupt):
        return "interrupted (Ctrl-C, SIGINT)"
    if isinstance(e, Terminated):
        return "terminated (SIGTERM)"
    return "failed (the error below)"


def run_stream(localizer: Localizer, frames: Limited, sinks: list[ResultSink], log: ResultLog | None,
               summary: RunSummary, batch_size: int, count: int | None, source: str) -> None:
    """Match ``frames`` and give every answer to every sink (signals held while a line is written, so that the
    log holds whole lines); however the stream ends, close every sink (the log keeps what was written) and
    say the summary on stderr; then raise what ended it (Ctrl-C, SIGTERM, a failure; a closed standard
    output ends it quietly, exit 0)."""
    shown = count is not None and sys.stderr.isatty()    # the progress bar
    lead = "\n" if shown else ""                          # a line of its own, off the bar

    def skip(frame: Frame) -> None:
        summary.skip()
        typer.echo(f"{lead}vpr-edge: warning: {printable(frame.error)}; frame skipped", err=True)

    start = time.monotonic()
    failure: BaseException | None = None
    piped = False
    try:
        with typer.progressbar(length=count or 0, label="localizing", file=sys.stderr,
                               hidden=not shown) as bar:
            for frame, match in localizer.answers(frames, batch_size, skip):
                with held_signals():
                    for sink in sinks:
                        sink.write(match, frame)
                    due = summary.add(match, frame)
                for warning in due:
                    typer.echo(f"{lead}vpr-edge: warning: {printable(warning)}", err=True)
                bar.update(1)
    except BrokenPipeError:       # the reader went away (``| head``): the stream's end, said quietly
        piped = True
    except BaseException as e:    # Ctrl-C, SIGTERM, a failure: the sinks are closed, what is written kept
        failure = ctrl_c(e)
    wall = time.monotonic() - start
    complete = failure is None and not piped and frames.reason is None
    failed = failure is not None and not isinstance(failure, (KeyboardInterrupt, Terminated))
    with held_signals():          # a second Ctrl-C acts once the log is in place
        closing = _close_all(sinks, complete, failed)
    if failure is None and not piped and summary.frames == 0:
        if closing is not None:
            raise closing
        if frames.reason is None:
            raise VprError(f"{source}: none of its frames could be decoded")
    ended = "standard output closed by its reader" if piped else \
        _ended_by(failure) if failure is not None else frames.reason or "end of the stream"
    if summary.frames or summary.skipped or failure is None or not isinstance(failure, VprError):
        for line in summary.lines(wall, ended):
            _said(line)
        if log is not None and log.target is not None:
            _said(f"no line written; {log.target} left as it was" if not log.lines else
                  f"{log.lines} lines kept in {log.kept} (the run failed); {log.target} "
                  f"{'left as it was' if log.had_older else 'not made'}" if log.failed
                  else f"{log.lines} lines kept in {log.kept}")
    if failure is not None:
        raise failure
    if closing is not None:
        raise closing


def _close_all(sinks: list[ResultSink], complete: bool, failed: bool = False) -> BaseException | None:
    """Close every sink, even when one fails; the first failure, if any."""
    first = None
    for sink in sinks:
        try:
            sink.close(complete, failed)
        except Exception as e:   # noqa: BLE001 - said after the others are closed
            first = first or e
    return first
