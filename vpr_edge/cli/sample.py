"""``vpr-edge sample``: copy a bundled demo sample out of the package (``resources.copy_sample``) and say what
was copied where."""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from vpr_edge.cli.common import app, user_errors
from vpr_edge.resources import SAMPLES, copy_sample


@app.command("sample")
def sample_cmd(name: str = typer.Argument("corridor", metavar="NAME", help="The sample to copy: "
                                          + "; ".join(f"{k} ({v})" for k, v in SAMPLES.items()) + "."),
               dest: Optional[Path] = typer.Option(None, "--to", help="New folder to copy it to (default: NAME in "
                                                   "the current folder; refused if it exists).")) -> None:
    """Copy a bundled demo sample to a new folder, to try build-map, localize and evaluate on: ref/ (the
    reference frames), query/ (the query frames), ground_truth.csv and a synthetic positions.csv to show
    answers as positions (its ReadMe.txt says how it was drawn and what to cite)."""
    with user_errors():
        where = copy_sample(name, dest)
        typer.echo(f"copied the bundled sample {name} ({SAMPLES[name]}) to {where}/: ref/ "
                   f"({len(list((where / 'ref').iterdir()))} frames), query/ "
                   f"({len(list((where / 'query').iterdir()))} frames), ground_truth.csv, positions.csv (synthetic, "
                   f"see ReadMe.txt)", err=True)
