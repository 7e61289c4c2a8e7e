"""``vpr-edge sample``: copy the bundled demo sample out of the package (``resources.copy_sample``)."""
from __future__ import annotations

from pathlib import Path

import typer

from vpr_edge.cli.common import app, user_errors
from vpr_edge.resources import SAMPLES, copy_sample


@app.command("sample")
def sample_cmd(dest: Path = typer.Argument(..., help="New folder to create (refused if it exists)."),
               name: str = typer.Option("corridor", help="Which sample: " + ", ".join(SAMPLES) + ".")) -> None:
    """Copy the bundled demo sample (Corridor, Milford 2013: 111 reference and 111 query frames, 160x120,
    with ground_truth.csv, and a synthetic positions.csv to show answers as positions) to a new folder, to try
    build-map, localize and evaluate on."""
    with user_errors():
        where = copy_sample(dest, name)
        typer.echo(f"wrote {where}: ref/ ({len(list((where / 'ref').iterdir()))} frames), query/ "
                   f"({len(list((where / 'query').iterdir()))} frames), ground_truth.csv, positions.csv (synthetic, "
                   f"see ReadMe.txt)", err=True)
