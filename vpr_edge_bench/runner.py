"""The one runner of the experiments: ``python -m vpr_edge_bench NAME [OPTIONS]`` runs the experiment NAME,
``python -m vpr_edge_bench`` lists them, one line each.

An experiment is a module of ``vpr_edge_bench.experiments`` (NAME is its module name with ``-`` for ``_``):
its docstring's first paragraph says in a line what it measures (``summary``), the rest how; its
``main(argv)`` parses the options (``parser``) and runs, bad input reported in one line with exit code 2
before any work (``run_checked``).
Listing reads the docstrings without importing the modules (no model, no torch loaded to list them).
"""
from __future__ import annotations

import argparse
import ast
import importlib
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from vpr_edge.errors import VprError, one_line_errors

PROG = "python -m vpr_edge_bench"
EXPERIMENTS_DIR = Path(__file__).resolve().parent / "experiments"


def experiment_name(module: str) -> str:
    """A module's experiment name: ``vpr_edge_bench.experiments.lost_tradeoff`` -> ``lost-tradeoff``."""
    return module.rsplit(".", 1)[-1].replace("_", "-")


def summary(doc: str | None) -> str:
    """A docstring's first paragraph, on one line."""
    return " ".join((doc or "").strip().split("\n\n")[0].split())


def experiments() -> dict[str, str]:
    """Every registered experiment (a module of ``experiments``), by name, in name order -> its ``summary``."""
    return {experiment_name(path.stem): summary(ast.get_docstring(ast.parse(path.read_text(encoding="utf-8"))))
            for path in sorted(EXPERIMENTS_DIR.glob("*.py")) if not path.name.startswith("_")}


def listing() -> str:
    """What ``python -m vpr_edge_bench`` prints: how to run one, then each experiment and its summary."""
    table = experiments()
    width = max(map(len, table))
    return "\n".join([f"usage: {PROG} NAME [OPTIONS]   ({PROG} NAME --help: its options)", "", "experiments:"]
                     + [f"  {name:<{width}}  {summary}" for name, summary in table.items()])


def parser(module: str, doc: str | None) -> argparse.ArgumentParser:
    """An experiment's option parser: named ``python -m vpr_edge_bench NAME``, described by its docstring's
    ``summary``, the rest of the docstring as its epilog."""
    rest = (doc or "").strip().partition("\n\n")[2]
    return argparse.ArgumentParser(prog=f"{PROG} {experiment_name(module)}", description=summary(doc),
                                   epilog=rest.strip() or None, formatter_class=argparse.RawDescriptionHelpFormatter)


def check_tolerance(tolerance: int) -> int:
    """An experiment's ``--tolerance`` (frames either side counted right): VprError below 0."""
    if tolerance < 0:
        raise VprError(f"--tolerance must be >= 0, got {tolerance}")
    return tolerance


def run_checked(module: str, work: Callable[[], int]) -> int:
    """Run an experiment's ``work``: a VprError or a refused file becomes ``NAME: error: message`` on stderr
    and exit code 2 (``errors.one_line_errors``); the library's inputs are said as the experiment's options
    (an experiment is a command line, as ``vpr-edge``'s commands are: ``cli.common.flag``)."""
    from vpr_edge.cli.common import flag
    from vpr_edge.errors import input_names

    with input_names(flag):
        return one_line_errors(experiment_name(module), work)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the experiment ``argv[0]`` with the rest as its options; none: list them (exit 0); an unknown name:
    one line on stderr, exit 2."""
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0] in ("-h", "--help"):
        print(listing())
        return 0
    table = experiments()
    if args[0] not in table:
        print(f"vpr_edge_bench: error: no experiment {args[0]!r}; {PROG} lists them ({', '.join(table)})",
              file=sys.stderr)
        return 2
    module = importlib.import_module(f"vpr_edge_bench.experiments.{args[0].replace('-', '_')}")
    return module.main(args[1:])
