"""``vpr-edge bench``: options in, ``profiling.sweep.plan_bench`` and ``run_bench`` called, a table (and
--json) out."""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Optional

import typer

from vpr_edge.cli.common import app, user_errors
from vpr_edge.files.atomic import atomic_output
from vpr_edge.files.checks import check_not_input, check_writable, output_path
from vpr_edge.profiling.sweep import DEFAULT_FRAMES, header_lines, plan_bench, row_line, run_bench, verdict_line


@app.command("bench")
def bench_cmd(
    map_path: Path = typer.Argument(..., metavar="MAP", help="Map file written by build-map."),
    frames: int = typer.Option(DEFAULT_FRAMES, "--frames", help="Frames timed a setting (after 3 warm-up "
                               "frames); bounds the time the bench takes."),
    threads: Optional[int] = typer.Option(None, "--threads", help="Time 1 to this many threads (default: every "
                                          "core this process may use; no more than that)."),
    fps: Optional[float] = typer.Option(None, "--fps", help="The camera's frame rate: name the setting that "
                                        "sustains it (fp32 before int8, then the fewest threads); exit code 1 "
                                        "if none does."),
    json_text: Optional[str] = typer.Option(None, "--json", help="Also write the record here (JSON: the "
                                            "host, the map, every setting's figures, the pick), e.g. for a "
                                            "fleet's records."),
) -> None:
    """Time the per-frame chain on this machine, stage by stage (decode, front end, encode, match), for each
    precision the map's model offers here (fp32, int8) and 1 to N threads, each setting in a process of its
    own (its start-up and peak memory its own); print the frames a second each sustains and, with --fps,
    the setting to run localize with. Frames: the map's references if their folder is here, else synthetic
    frames of the references' size (the worst case: the matcher never locks); a map of descriptors: its own
    places (docs/deploy.md)."""
    with user_errors():
        out = output_path(json_text) if json_text else None
        if out:
            check_writable(out)
            check_not_input({"--json": out}, [map_path])
        plan = plan_bench(map_path, frames, threads, fps)
        from vpr_edge.profiling.sweep import host

        for line in header_lines(plan, host()):
            typer.echo(line)
        sys.stdout.flush()
        record = run_bench(plan, on_row=lambda row: (typer.echo(row_line(row)), sys.stdout.flush()))
        typer.echo(verdict_line(record))
        if out:
            with atomic_output(out) as tmp:
                tmp.write_text(json.dumps(record, indent=1) + "\n")
        if fps is not None and record.get("pick") is None:
            raise typer.Exit(1)
