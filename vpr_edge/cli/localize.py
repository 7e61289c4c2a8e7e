"""``vpr-edge localize``: options in, ``api.Localizer.run`` over the stream, one result line per frame out."""
from __future__ import annotations

import contextlib
import csv
import json
import sys
from collections.abc import Callable, Iterator
from enum import Enum
from pathlib import Path
from typing import IO, Optional

import typer

from vpr_edge.api import FIELDS, Localizer, Match
from vpr_edge.cli.common import (LIST_PARAMS, MODE_HELP, PARAM_HELP, PRECISION_HELP, THREADS_HELP, ModeOpt,
                                 PrecisionOpt, app, params_for, user_errors, with_param_options)
from vpr_edge.errors import MapChanged, VprError, printable
from vpr_edge.features.choice import DEFAULT_PRECISION
from vpr_edge.files import atomic_output, check_not_input, check_writable, output_path
from vpr_edge.frames.images import Frame, open_stream
from vpr_edge.matchers import MATCHERS, get_matcher
from vpr_edge.matchers.verdict import TARGET_PRECISION


class VariantOpt(str, Enum):
    distance = "distance"
    similarity = "similarity"


class FormatOpt(str, Enum):
    csv = "csv"
    jsonl = "jsonl"


CSV_COLUMNS = FIELDS


def _cell(value) -> object:
    """A CSV cell: None empty, floats to 6 decimals (times to the microsecond), bools 0/1."""
    if value is None:
        return ""
    if isinstance(value, bool):
        return int(value)
    if isinstance(value, float):
        return f"{value:.6f}"
    return value


@contextlib.contextmanager
def _writing(where: str) -> Iterator[None]:
    """A failed write (disk full, device gone) becomes one line naming ``where``; a closed pipe passes."""
    try:
        yield
    except BrokenPipeError:
        raise
    except OSError as e:
        raise VprError(f"{where}: cannot write results ({e.strerror or e})") from None


def results_writer(fmt: str, stream: IO[str], where: str) -> Callable[[Match], None]:
    """Write the header now; return a function writing one result line and flushing it (a line per frame,
    as it happens)."""
    if fmt == "csv":
        w = csv.writer(stream, lineterminator="\n")
        with _writing(where):
            w.writerow(CSV_COLUMNS)

        def line(m: Match) -> None:
            w.writerow([_cell(v) for v in m.fields().values()])
    else:
        def line(m: Match) -> None:
            fields = {k: round(v, 6) if isinstance(v, float) and k != "stamp" else v for k, v in m.fields().items()}
            stream.write(json.dumps(fields) + "\n")

    def write(m: Match) -> None:
        with _writing(where):
            line(m)
            stream.flush()
    return write


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
    mode: ModeOpt = typer.Option("stream", metavar="MATCHER", help=MODE_HELP),
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
        None, help="Modes whose score is the probability that the answer is right (stream-prob): the line, "
                   "answers below it are lost (default %.2f)." % TARGET_PRECISION),
    param: Optional[list[str]] = typer.Option(None, "--param", metavar="KEY=VALUE", help=PARAM_HELP),
    calibration: Optional[Path] = typer.Option(None, help="A calibration (evaluate --save-calibration on a "
                                               "labelled drive of this route): each line's confidence is then "
                                               "the probability that its answer is right."),
    list_params: bool = LIST_PARAMS,
    out_text: Optional[str] = typer.Option(None, "--out", "-o", help="Write results here instead of stdout "
                                           "(written to a temporary file, renamed when the stream is done; "
                                           "never over an input; a symbolic link is written through)."),
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
    position fields are empty when lost. Undecodable frames are reported on stderr and skipped."""
    with user_errors():
        out = output_path(out_text) if out_text else None
        if out:
            check_writable(out)
            check_not_input({"--out": out}, [map_path, stream, model, timestamps, calibration])
        else:
            with _writing("stdout"):
                sys.stdout.write("")      # a closed standard output fails here, before any work
        suffix_fmt = {".csv": "csv", ".jsonl": "jsonl", ".json": "jsonl"}.get(out.suffix.lower()) if out else None
        if fmt and suffix_fmt and fmt.value != suffix_fmt:
            raise VprError(f"{out}: --format {fmt.value} contradicts the file's {out.suffix} suffix")
        params = params_for(mode.value, {"variant": variant.value if variant else None, "open_ends": open_ends,
                                         "decay": decay, "window": window})
        params = with_param_options(get_matcher(mode.value), params, param or [])
        frames, count = open_stream(stream, timestamps, topic)
        localizer = Localizer(map_path, model=model, mode=mode.value, params=params,
                              min_confidence=min_confidence, threads=threads, calibration=calibration,
                              precision=precision.value, target_precision=target_precision)
        localizer.query.check_source(stream)   # descriptors for a map of descriptors, images for one of images
        if precision.value == "auto" and "form" in localizer.front_description:   # what auto chose, said once
            typer.echo(f"vpr-edge: --precision auto: {localizer.front_description['model']} "
                       f"({localizer.front_description['form']})", err=True)
        chosen = fmt.value if fmt else (suffix_fmt or "csv")
        skipped = 0

        def skip(frame: Frame) -> None:
            nonlocal skipped
            skipped += 1
            typer.echo(f"\nvpr-edge: warning: {printable(frame.error)}; frame skipped", err=True)  # \n: off the bar

        changed: MapChanged | None = None
        with contextlib.ExitStack() as stack:
            if out:
                sink = stack.enter_context(open(stack.enter_context(atomic_output(out)), "w", newline=""))
            else:
                sink = sys.stdout
            write = results_writer(chosen, sink, str(out or "stdout"))
            written = 0
            with typer.progressbar(length=count or 0, label="localizing", file=sys.stderr,
                                   hidden=count is None or not sys.stderr.isatty()) as bar:
                try:
                    for match in localizer.run(frames, batch_size, skip):
                        write(match)
                        written += 1
                        bar.update(1)
                except MapChanged as e:   # stop here; what was written is kept (the output is renamed)
                    changed = e
            if written == 0 and changed is None:
                raise VprError(f"{stream}: none of its frames could be decoded")
        if changed is not None:
            raise changed
        if skipped:
            typer.echo(f"vpr-edge: {skipped} undecodable frame(s) skipped", err=True)
