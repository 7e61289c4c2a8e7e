"""The command line: one small module per command, each parsing its options, calling one library function
and printing; ``common`` holds what they share. ``main`` is the console script."""
from __future__ import annotations

import sys

import typer

from vpr_edge.cli import adapt, bench, build_map, evaluate, info, localize, sample  # noqa: F401 - each registers its command
from vpr_edge.cli.common import app
from vpr_edge.errors import Terminated, os_error_line, terminate_cleanly

__all__ = ["app", "main"]


class ClosedOutput:
    """Standard output when the process was started without one: writing to it is an error naming it."""

    def write(self, text: str) -> int:
        import errno

        raise OSError(errno.EBADF, "standard output is closed", "stdout")

    def flush(self) -> None:
        pass

    def isatty(self) -> bool:
        return False

    def fileno(self) -> int:
        import errno

        raise OSError(errno.EBADF, "standard output is closed", "stdout")


# click's UsageError and ClickException, whether typer vendors click or depends on it
_USAGE_ERROR, _CLICK_ERROR = typer.BadParameter.__mro__[1:3]


def main() -> None:
    """Console-script entry point: a usage error (unknown option, missing argument) is one line on stderr,
    ``vpr-edge: error: COMMAND: problem (see 'COMMAND -h')``, exit code 2, like every other refusal."""
    terminate_cleanly()
    if sys.stdout is None:          # started with standard output closed (`>&-`)
        sys.stdout = ClosedOutput()
    try:
        rc = app(prog_name="vpr-edge", standalone_mode=False)
    except _USAGE_ERROR as e:
        if type(e).__name__ == "NoArgsIsHelpError":          # bare `vpr-edge` or `vpr-edge CMD`: the help
            e.show()
            sys.exit(e.exit_code)
        where = e.ctx.command_path if e.ctx is not None else "vpr-edge"
        print(f"vpr-edge: error: {where}: {e.format_message().rstrip('.')} (see '{where} -h')", file=sys.stderr)
        sys.exit(2)
    except _CLICK_ERROR as e:
        print(f"vpr-edge: error: {e.format_message()}", file=sys.stderr)
        sys.exit(e.exit_code)
    except typer.Abort:
        print("vpr-edge: aborted", file=sys.stderr)
        sys.exit(1)
    except OSError as e:            # writing the help or the version to a closed or full output
        print(f"vpr-edge: error: {os_error_line(e)}", file=sys.stderr)
        sys.exit(2)
    except Terminated:              # SIGTERM while parsing options, before any work
        print("vpr-edge: terminated", file=sys.stderr)
        sys.exit(Terminated.exit_code)
    sys.exit(rc if isinstance(rc, int) else 0)

