"""The one exception type the CLI turns into a one-line error message."""
from __future__ import annotations


class VprError(Exception):
    """A user-facing error: bad input file, mismatched map, missing dependency. Message is one line."""
