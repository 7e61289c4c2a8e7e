"""User-facing problems: the exception the CLI turns into one line, and warnings said once each."""
from __future__ import annotations

import sys
from collections.abc import Callable

_said: set[str] = set()


class VprError(Exception):
    """A user-facing error: bad input file, mismatched map, missing dependency. Message is one line."""


def warn(message: str) -> None:
    """Print ``vpr-edge: warning: message`` on stderr, once per distinct message in this process."""
    if message not in _said:
        _said.add(message)
        print(f"vpr-edge: warning: {message}", file=sys.stderr, flush=True)


def os_error_line(e: OSError) -> str:
    """A file the system refused (disk full, permission): ``file: reason``, or the reason alone."""
    return f"{e.filename}: {e.strerror or e}" if e.filename else str(e.strerror or e)


def one_line_errors(prog: str, main: Callable[[], int]) -> int:
    """Run a command-line ``main``; a VprError, or a file the system refuses (OSError), becomes
    ``prog: error: message`` on stderr and exit code 2 instead of a traceback (for the tools run by
    ``python``; the ``vpr-edge`` CLI does the same through typer)."""
    try:
        return main()
    except VprError as e:
        print(f"{prog}: error: {e}", file=sys.stderr)
    except OSError as e:
        print(f"{prog}: error: {os_error_line(e)}", file=sys.stderr)
    return 2
