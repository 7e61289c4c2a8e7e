"""``vpr-edge info``: a map's size and settings as JSON (``map.summary.summary``)."""
from __future__ import annotations

import json
from pathlib import Path

import typer

from vpr_edge.cli.common import app, user_errors
from vpr_edge.map.summary import summary


@app.command("info")
def info_cmd(map_path: Path = typer.Argument(..., help="Map file written by build-map.")) -> None:
    """Describe a map: references, encoding size, codebook, model and settings (JSON on stdout)."""
    with user_errors():
        typer.echo(json.dumps(summary(map_path), indent=1, sort_keys=True))
