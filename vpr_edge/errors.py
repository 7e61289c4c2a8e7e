"""User-facing problems: the exception the CLI turns into one line, and warnings said once each."""
from __future__ import annotations

import sys

_said: set[str] = set()


class VprError(Exception):
    """A user-facing error: bad input file, mismatched map, missing dependency. Message is one line."""


def warn(message: str) -> None:
    """Print ``vpr-edge: warning: message`` on stderr, once per distinct message in this process."""
    if message not in _said:
        _said.add(message)
        print(f"vpr-edge: warning: {message}", file=sys.stderr, flush=True)
