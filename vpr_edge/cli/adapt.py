"""``vpr-edge adapt``: options in, ``map.adapt.adapt_map`` called, one line out."""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from vpr_edge.cli.common import THREADS_HELP, app, user_errors
from vpr_edge.encoders.adapt import RANKS, SHRINK
from vpr_edge.errors import InputError, printable
from vpr_edge.files.checks import output_path
from vpr_edge.frames.images import Frame
from vpr_edge.map.adapt import ALIGNED, RADIUS_M, LabelledDrive, adapt_map
from vpr_edge.threads import use_threads


@app.command("adapt")
def adapt_cmd(
    map_path: Path = typer.Argument(..., metavar="MAP", help="Map from build-map (not adapted already)."),
    drives: list[str] = typer.Argument(..., metavar="DRIVE...", help="Labelled drives of the route: folders of "
                                       "frames, videos or descriptor files."),
    out: str = typer.Option(..., "--out", "-o", help="The adapted map to write (a new file; MAP is kept)."),
    gt: Optional[list[Path]] = typer.Option(None, "--gt", help="Each drive's ground truth, in the drives' order: "
                                            "a query,references CSV or a (Q, R) .npy (docs/formats.md)."),
    aligned: bool = typer.Option(False, "--aligned", help="Each drive is frame-aligned with the map: frame i "
                                 "shows place i."),
    gt_positions: Optional[list[Path]] = typer.Option(None, "--gt-positions", help="Each drive's positions CSV "
                                                      "(as build-map --positions reads), matched with the map's "
                                                      "own positions within --radius."),
    radius: float = typer.Option(RADIUS_M, min=0.0, help="With --gt-positions: metres within which a reference "
                                 "is a frame's place."),
    rank: Optional[int] = typer.Option(None, min=1, help="Directions of within-place change to whiten (fewer "
                                       "with fewer labelled frames); default: "
                                       f"{' or '.join(map(str, RANKS))}, chosen on the drives' own held-out "
                                       "places."),
    shrink: float = typer.Option(SHRINK, min=1e-6, help="How far each direction's variance is shrunk towards "
                                 "the mean (small: whitened fully)."),
    model: Optional[Path] = typer.Option(None, help="ONNX feature model (default: the map's own)."),
    batch_size: int = typer.Option(8, min=1, help="Frames per model run."),
    threads: int = typer.Option(0, min=0, help=THREADS_HELP),
) -> None:
    """Fit a map to its route: learn from labelled drives which changes of the encodings leave the place the
    same (season, light, camera), suppress them, and write the adapted map. localize and evaluate then map
    each frame the same way. At least 50 labelled frames are needed (encoders.adapt.MIN_PAIRS)."""
    with user_errors():
        given = [aligned, bool(gt), bool(gt_positions)]
        if sum(given) != 1:
            raise InputError("give the drives' labels one way: {opt.aligned}, {opt.gt} or {opt.gt_positions}")
        labels = gt or gt_positions or []
        if not aligned and len(labels) != len(drives):
            raise InputError("{n} drives but {m} label files: give one for each drive, in order", n=len(drives),
                             m=len(labels))
        labelled = [LabelledDrive(d, ALIGNED if aligned else str(labels[i]), bool(gt_positions), radius)
                    for i, d in enumerate(drives)]

        def skipped(frame: Frame) -> None:
            typer.echo(f"vpr-edge: warning: skipped {printable(frame.name)}: {frame.error}", err=True)

        line = adapt_map(map_path, labelled, output_path(out), rank, shrink, model, batch_size,
                         use_threads(threads), skipped)
        typer.echo(line, err=True)
