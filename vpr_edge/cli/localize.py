"""``vpr-edge localize``: options in, ``api.Localizer.run`` over the stream, one result line per frame out."""
from __future__ import annotations

import sys
import time
from enum import Enum
from pathlib import Path
from typing import Optional

import typer

from vpr_edge.api import Localizer
from vpr_edge.cli.common import (LIST_PARAMS, MODE_HELP, PARAM_HELP, PRECISION_HELP, THREADS_HELP, ModeOpt,
                                 PrecisionOpt, app, params_for, user_errors, with_param_options)
from vpr_edge.errors import Terminated, VprError, ctrl_c, held_signals, printable
from vpr_edge.features.choice import DEFAULT_PRECISION
from vpr_edge.files import check_not_input, check_writable, output_path
from vpr_edge.frames.images import Frame, GreyFrames, open_stream
from vpr_edge.frames.limits import Limited
from vpr_edge.matchers import DEFAULT_MATCHER, MATCHERS, get_matcher
from vpr_edge.matchers.constants import TARGET_PRECISION
from vpr_edge.outputs.sink import ResultSink
from vpr_edge.outputs.log import SUFFIX_FORMATS, ResultLog, writing
from vpr_edge.outputs.live import check_live, is_mcap, live_sinks
from vpr_edge.outputs.summary import RunSummary, reference_size


class VariantOpt(str, Enum):
    distance = "distance"
    similarity = "similarity"


class FormatOpt(str, Enum):
    csv = "csv"
    jsonl = "jsonl"


@app.command("localize")
def localize_cmd(
    map_path: Path = typer.Option(..., "--map", "-m", help="Map file written by build-map."),
    stream: str = typer.Option(..., "--stream", "-s", metavar="SOURCE",
                               help="Folder of frames (file-name order), a video file, a camera (0, 1, ... "
                                    "or /dev/video0), a network stream (rtsp://...), a ROS bag (--topic), or "
                                    "for a map of descriptors a file of them (.npy rows, hloc .h5)."),
    model: Optional[Path] = typer.Option(None, help="ONNX feature model; must be the map's model (default: "
                                         "$VPR_EDGE_MODEL if set, else the file the map was built with if it "
                                         "still exists, else the bundled one)."),
    mode: ModeOpt = typer.Option(DEFAULT_MATCHER, metavar="MATCHER", help=MODE_HELP),
    variant: Optional[VariantOpt] = typer.Option(None, help="DTW modes: distance (minimise summed 1 - cosine, "
                                                 "default) or similarity (maximise summed cosine, the thesis)."),
    open_ends: Optional[bool] = typer.Option(None, "--open-ends/--fixed-ends", help="DTW modes: let the path "
                                             "start and end anywhere, 0-4 references per frame (dtw-open)."),
    decay: Optional[float] = typer.Option(None, min=0.01, max=0.999, help="stream / stream-dtw: each frame "
                                          "discounts the past by this factor (about 1/(1-decay) frames kept)."),
    window: Optional[int] = typer.Option(None, min=0, help="stream: local search, references either side of a "
                                         "firm lock read per frame, on routes over 4x this (default %d; 0 = "
                                         "every reference every frame)." % MATCHERS["stream"].params["window"]),
    min_confidence: Optional[float] = typer.Option(
        None, help="Frames scoring below this are reported lost (reference and position fields empty). "
                   "Default: the mode's own (stream: %.1f; other modes: never lost)."
                   % MATCHERS["stream"].min_confidence),
    target_precision: Optional[float] = typer.Option(
        None, help="Modes whose score is the probability that the answer is right (stream-filter): the line, "
                   "answers below it are lost (default %.2f). With --calibration, any mode: the line where the "
                   "labelled drive's answers at least as sure were right this often; else refused for another "
                   "mode (stream: its line is --min-confidence)." % TARGET_PRECISION),
    param: Optional[list[str]] = typer.Option(None, "--param", metavar="KEY=VALUE", help=PARAM_HELP),
    calibration: Optional[Path] = typer.Option(None, help="A calibration (evaluate --save-calibration on a "
                                               "labelled drive of this route): each line's confidence is then "
                                               "the probability that its answer is right."),
    list_params: bool = LIST_PARAMS,
    out_text: Optional[str] = typer.Option(None, "--out", "-o", help="Write results here instead of stdout: "
                                           "lines go to NAME.part as frames are matched, renamed NAME when the "
                                           "stream ends however it ends (Ctrl-C, SIGTERM, a limit, a failure: "
                                           "every line written is kept); never over an input; a symbolic link "
                                           "is written through."),
    view: bool = typer.Option(False, "--view", help="Show the stream in a Rerun Viewer as it is matched: the "
                              "frame beside the matched reference, where on the route, score, confidence and "
                              "lost stretches (view extra; one already on port 9876 is used, else one is "
                              "started with its usage analytics off)."),
    rerun_text: Optional[str] = typer.Option(None, "--rerun", metavar="FILE.rrd", help="Record what --view "
                                             "shows to this Rerun file (view extra; renamed into place when the "
                                             "stream ends)."),
    max_frames: Optional[int] = typer.Option(None, "--max-frames", min=1, metavar="N",
                                             help="Stop after N frames read from the stream (exit 0)."),
    duration: Optional[float] = typer.Option(None, min=0.001, metavar="SECONDS",
                                             help="Stop reading frames this many seconds after the stream "
                                                  "starts (exit 0)."),
    fmt: Optional[FormatOpt] = typer.Option(None, "--format", help="csv or jsonl (default: from --out's "
                                            "suffix, csv on stdout)."),
    topic: Optional[str] = typer.Option(None, help="With a ROS 1/2 bag or MCAP file: the image topic "
                                        "(sensor_msgs/Image or CompressedImage; frames stamped by their headers)."),
    timestamps: Optional[Path] = typer.Option(None, help="With a folder of frames: a CSV frame,stamp giving "
                                              "each frame's time in seconds (videos and live sources are "
                                              "stamped by themselves)."),
    batch_size: int = typer.Option(1, min=1, help="Frames per model run (1 = lowest latency)."),
    threads: int = typer.Option(0, min=0, help=THREADS_HELP),
    precision: PrecisionOpt = typer.Option(DEFAULT_PRECISION, help=PRECISION_HELP),
) -> None:
    """Localise every frame of a stream against a map. One line per frame: frame index, name and time
    (seconds), the matched reference's index and name, its position (x,y or lat,lon, heading, metres along
    the route) when the map has positions, score (higher = more confident) and lost (0/1); the reference and
    position fields are empty when lost. Undecodable frames are reported on stderr and skipped. When the
    stream ends (its end, a limit, Ctrl-C, SIGTERM, a failure) every line written is kept and a summary goes
    to stderr (docs/usage.md, On the vehicle)."""
    with user_errors():
        out = output_path(out_text) if out_text else None
        if out:
            check_writable(out)
            check_not_input({"--out": out}, [map_path, stream, model, timestamps, calibration])
        else:
            with writing("stdout"):
                sys.stdout.write("")      # a closed standard output fails here, before any work
        suffix_fmt = SUFFIX_FORMATS.get(out.suffix.lower()) if out else None
        if fmt and suffix_fmt and fmt.value != suffix_fmt:
            raise VprError(f"{out}: --format {fmt.value} contradicts the file's {out.suffix} suffix")
        record = output_path(rerun_text) if rerun_text else None
        check_live(out, fmt.value if fmt else None, view, record)     # the extras, before the work
        if record is not None:
            check_writable(record)
            check_not_input({"--rerun": record}, [map_path, stream, model, timestamps, calibration])
        params = params_for(mode.value, {"variant": variant.value if variant else None, "open_ends": open_ends,
                                         "decay": decay, "window": window})
        params = with_param_options(get_matcher(mode.value), params, param or [])
        frames, count = open_stream(stream, timestamps, topic)
        localizer = Localizer(map_path, model=model, mode=mode.value, params=params,
                              min_confidence=min_confidence, threads=threads, calibration=calibration,
                              precision=precision.value, target_precision=target_precision)
        localizer.query.check_source(stream)   # descriptors for a map of descriptors, images for one of images
        if localizer.drive_line:   # the line in force, from the labelled drive
            typer.echo(f"vpr-edge: lost below score {localizer.threshold:.6g}: where {calibration}'s labelled drive "
                       f"shows precision {target_precision:g}", err=True)
        if precision.value == "auto" and "form" in localizer.front_description:   # what auto chose, said once
            typer.echo(f"vpr-edge: --precision auto: {localizer.front_description['model']} "
                       f"({localizer.front_description['form']})", err=True)
        folder = stream if Path(stream).is_dir() else None   # a folder's frames named by their paths
        limited = Limited(GreyFrames.of(localizer.query.front).watch(frames, folder), max_frames, duration)
        if max_frames is not None and count is not None:
            count = min(count, max_frames)
        sinks: list[ResultSink] = live_sinks(localizer, map_path, stream, out, view, record)
        log = None if is_mcap(out) else ResultLog(fmt.value if fmt else (suffix_fmt or "csv"), out)
        sinks = ([log] if log else []) + sinks   # every output of the stream: each gets every answer, then close()
        run_stream(localizer, limited, sinks, log, RunSummary(reference_size(localizer.map.meta)), batch_size,
                   count, stream)


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
