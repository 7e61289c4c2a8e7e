"""What every command shares: the typer app, one-line errors (exit 2), option enums read from the registries,
help texts, and the --param parsing."""
from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator
from enum import Enum

import typer

from vpr_edge import __version__
from vpr_edge.encoders import ENCODERS
from vpr_edge.errors import InputError, Terminated, VprError, ctrl_c, input_names, os_error_line, printable
from vpr_edge.features import FRONT_ENDS
from vpr_edge.features.choice import PRECISIONS
from vpr_edge.features.conventions import LAYOUTS
from vpr_edge.features.resize import RESIZE
from vpr_edge.index.encodings import STORAGES
from vpr_edge.matchers import MATCHERS, Matcher, param_key

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  rich_markup_mode=None, context_settings={"help_option_names": ["-h", "--help"],
                                                           "max_content_width": 100})


def _version(value: bool) -> None:
    if value:
        typer.echo(f"vpr-edge {__version__}")
        raise typer.Exit()


@app.callback()
def _main(version: bool = typer.Option(False, "--version", callback=_version, is_eager=True,
                                       help="Print the version and exit.")) -> None:
    """Visual place recognition on a CPU: build a map of reference images, then localise a stream of frames
    against it (ONNX features, Improved Fisher Vectors, sequence matching)."""


ModeOpt = Enum("ModeOpt", {name: name for name in MATCHERS}, type=str)  # type: ignore[misc]
StorageOpt = Enum("StorageOpt", {name: name for name in STORAGES}, type=str)  # type: ignore[misc]
FrontOpt = Enum("FrontOpt", {name: name for name in FRONT_ENDS}, type=str)  # type: ignore[misc]
ResizeOpt = Enum("ResizeOpt", {name: name for name in RESIZE}, type=str)  # type: ignore[misc]
LayoutOpt = Enum("LayoutOpt", {name: name for name in LAYOUTS}, type=str)  # type: ignore[misc]
PrecisionOpt = Enum("PrecisionOpt", {name: name for name in PRECISIONS}, type=str)  # type: ignore[misc]
EncodingOpt = Enum("EncodingOpt", {name: name for name in ENCODERS}, type=str)  # type: ignore[misc]


# the library's inputs whose option is not their name with dashes: ``Source.pixels`` is ``--features pixels``,
# a matcher's ``params`` are each ``--param KEY=VALUE``, bench's ``max_threads`` is ``--threads``
# (``Truth.positions`` is said ``gt_positions``, apart from a map's positions: ``--gt-positions`` as it is)
FLAGS = {"pixels": "--features pixels", "params": "--param", "max_threads": "--threads"}


def flag(name: str) -> str:
    """The option that gives the library's input ``name`` on the command line: ``positions_topic`` ->
    ``--positions-topic``, or ``FLAGS[name]`` (``errors.InputError`` and every ``Message`` are said with these)."""
    return FLAGS.get(name) or "--" + name.replace("_", "-")


@contextlib.contextmanager
def user_errors() -> Iterator[None]:
    """Turn VprError into one line on stderr and exit code 2, the inputs it names said as options (``flag``);
    Ctrl-C into exit code 130, SIGTERM into 143 (temporary outputs removed on the way out)."""
    with input_names(flag):
        try:
            yield
        except InputError as e:
            typer.echo(f"vpr-edge: error: {printable(e.line(flag))}", err=True)
            raise typer.Exit(2) from None
        except (VprError, ValueError) as e:
            typer.echo(f"vpr-edge: error: {printable(str(e))}", err=True)
            raise typer.Exit(2) from None
        except BrokenPipeError:  # the reader went away (``| head``): stop quietly, as Unix tools do
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            raise typer.Exit(1) from None
        except OSError as e:  # disk full, permission lost mid-run: name the file and the reason
            typer.echo(f"vpr-edge: error: {printable(os_error_line(e))}", err=True)
            raise typer.Exit(2) from None
        except (KeyboardInterrupt, SystemError) as e:   # Ctrl-C, also inside a C extension (``ctrl_c``)
            if isinstance(e, SystemError) and ctrl_c(e) is e:   # a SystemError of its own
                raise
            typer.echo("vpr-edge: interrupted", err=True)
            raise typer.Exit(130) from None
        except Terminated:
            typer.echo("vpr-edge: terminated", err=True)
            raise typer.Exit(Terminated.exit_code) from None


MODEL_HELP = ("ONNX feature model exported by vpr_edge_export (default: $VPR_EDGE_MODEL if set, else the "
              "bundled EfficientNet-Lite0 tap whose input suits the references' frame size: 160x120 up to "
              "320x240 frames, 320x240 above).")
STANDARDISE_HELP = ("Standardise the cosines: take each traversal's own mean encoding away first, the map's "
                    "references' and a running mean of this stream's frames (docs/usage.md, \"Fitting vpr-edge to "
                    "your route\"). Finds a place from one frame more often across seasons; default on "
                    "(--raw-cosines: off).")
PRECISION_HELP = ("The model's numeric form: fp32 (default); int8: its int8 form, kept beside it (faster, less "
                  "accurate: docs/results.md); auto: int8 where this CPU has int8 dot-product instructions (x86 "
                  "VNNI, ARM dotprod), else fp32. `vpr-edge info MAP` says what auto runs here.")
THREADS_HELP = ("Threads for onnxruntime and NumPy's BLAS together, so the two pools never oversubscribe "
                "the cores (0 = one per core).")
PARAM_HELP = ("Set one of the matcher's parameters (repeatable), e.g. --param bias=1.6 --param lock=6: "
              "calibrating the stream's lost state on a drive of your own route (docs/matchers.md). Each "
              "matcher's parameters and defaults are listed at the end of this help; --list-params gives their "
              "meanings; evaluate --json records the values run.")
MODE_HELP = ("Matcher. Online (a result per frame): " + ", ".join(n for n, m in MATCHERS.items() if m.online)
             + ". Offline (results after the last frame): " + ", ".join(n for n, m in MATCHERS.items()
                                                                        if not m.online)
             + ". What each does: --list-params, docs/matchers.md.")


def _list_params(value: bool) -> None:
    if value:
        for m in MATCHERS.values():
            lost = f"; lost below {m.min_confidence}" if m.min_confidence is not None else ""
            typer.echo(f"{m.name} ({'online' if m.online else 'offline'}{lost}): {m.summary}")
            if m.params:
                typer.echo(m.params_help())
        raise typer.Exit()


LIST_PARAMS = typer.Option(False, "--list-params", callback=_list_params, is_eager=True,
                           help="Print every matcher with its parameters (--param KEY=VALUE), their defaults "
                                "and meanings, and exit.")


def _shown(value: object) -> str:
    """A parameter's value as ``--param`` reads it (bools as true/false)."""
    return str(value).lower() if isinstance(value, bool) else str(value)


def params_epilog() -> str:
    """Every matcher's parameters with their defaults, ``KEY=DEFAULT``, read from the registry (whose tables are
    ``matchers.params``): the end of ``localize -h`` and ``evaluate -h``. Matchers with the same parameters and
    defaults share a paragraph."""
    groups: dict[str, list[str]] = {}
    for m in MATCHERS.values():
        if m.params:
            groups.setdefault(", ".join(f"{k}={_shown(v)}" for k, v in m.params.items()), []).append(m.name)
    head = "\b\nMatcher parameters, set with --param KEY=VALUE, with their defaults\n(meanings: --list-params, " \
           "docs/matchers.md):"     # \b: click keeps these two lines as they are
    return "\n\n".join([head] + [f"{', '.join(names)}: {listed}" for listed, names in groups.items()])


PARAMS_EPILOG = params_epilog()


def param_options_for_all(matchers: dict[str, Matcher], items: list[str]) -> dict[str, Matcher]:
    """Each of ``matchers`` with the ``--param`` items whose key it has; VprError for a key none has (and
    ``parse_params``'s ValueError for a value one refuses)."""
    keys = [param_key(item) for item in items]
    for item, key in zip(items, keys):
        if not any(key in m.params for m in matchers.values()):
            raise VprError(f"--param {item!r}: none of the modes {','.join(matchers)} has a parameter {key!r}")
    return {name: m.with_params(**m.parse_params([i for i, k in zip(items, keys) if k in m.params]))
            for name, m in matchers.items()}
