"""The contract of a stream's output: one call per matched frame, one at the end."""
from __future__ import annotations

from typing import Protocol, runtime_checkable

from vpr_edge.api import Match
from vpr_edge.frames.frame import Frame


@runtime_checkable
class ResultSink(Protocol):
    """Receives each answer as it is made (``write``: the answer and the frame it answers, whose ``image`` may
    be None for a stream of descriptors) and is told once when the stream ends (``close``: ``complete`` False
    when the stream stopped early, by a signal, a limit or a failure; ``failed`` True for a failure, not a
    stop the user asked for: a file sink then keeps an older file of its name; what was written stays valid)."""

    def write(self, match: Match, frame: Frame | None) -> None: ...

    def close(self, complete: bool, failed: bool = False) -> None: ...
