"""A stream's own limits: at most so many frames, or so many seconds (``localize --max-frames``,
``--duration``), for a live source that would otherwise run until it is stopped."""
from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator

from vpr_edge.errors import Message
from vpr_edge.frames.frame import Frame


class Limited:
    """The frames of ``frames`` up to a limit: at most ``max_frames`` frames read from the source (undecodable
    ones included), none read once ``duration`` seconds (``clock``) have passed since the first was asked for.
    The source is not read past the limit. ``reason`` says which limit ended the stream (``max_frames N`` or
    ``duration S``, a ``Message``: said ``--max-frames N`` by the CLI); None while it runs and when the source ended by itself."""

    def __init__(self, frames: Iterable[Frame], max_frames: int | None = None, duration: float | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.frames = frames
        self.max_frames = max_frames
        self.duration = duration
        self.clock = clock
        self.reason: Message | None = None

    def __iter__(self) -> Iterator[Frame]:
        source = iter(self.frames)
        start = self.clock()
        taken = 0
        while True:
            if self.max_frames is not None and taken >= self.max_frames:
                self.reason = Message("{opt.max_frames} {n}", n=self.max_frames)
                return
            if self.duration is not None and self.clock() - start >= self.duration:
                self.reason = Message("{opt.duration} {s:g} s", s=self.duration)
                return
            try:
                frame = next(source)
            except StopIteration:
                return
            taken += 1
            yield frame
