"""The log of a stream: one CSV or JSON line per matched frame (``api.Match.fields``), a ``ResultSink``.

A stream's results are a log, valid up to the last frame matched, not a map that is whole or nothing. Written
to ``--out``: the lines go to ``NAME.part`` beside it as frames are matched (each line handed to the system at
once, so that a killed process loses none; fsync'd with each line (``SYNC_INTERVAL_S``), so that a power cut
loses at most the last frame), and ``NAME.part`` becomes ``NAME`` when the stream ends on its own or by the
user's stop (a limit, Ctrl-C, SIGTERM): a file of that name from an earlier run is replaced only then. A run
that fails (a write error, a full disk, a frame that ends the stream) keeps both: ``NAME`` as it was and its
own lines, whole, in ``NAME.part``. A run that matched no frame replaces nothing. One writer per log (a lock on ``NAME.part``); a ``NAME.part`` left
by a run that died without a word (SIGKILL, power cut) is made ``NAME`` by the next run to that name, its
last partial line cut, before the new run starts its own. Without ``--out`` the lines go to standard output,
flushed one by one. The header (CSV) is written with the first line, so a stream that fails to start
writes nothing."""
from __future__ import annotations

import contextlib
import csv
import io
import json
import os
import sys
import time
from pathlib import Path
from typing import IO

from vpr_edge.api import FIELDS, Match
from vpr_edge.files.atomic import adopt_mode
from vpr_edge.files.checks import is_special
from vpr_edge.frames.frame import Frame
from vpr_edge.outputs.part import Fd, open_output, part_path, writing

FORMATS = ("csv", "jsonl")
SUFFIX_FORMATS = {".csv": "csv", ".jsonl": "jsonl", ".json": "jsonl"}   # --out's suffix -> format
SYNC_INTERVAL_S = 0.0     # a file's lines are fsync'd at least this often, seconds (0: every line; and at the end)
CSV_COLUMNS = FIELDS


def _cell(value) -> object:
    """A CSV cell: None empty, floats to 6 decimals (times to the microsecond), bools 0/1."""
    if value is None:
        return ""
    if isinstance(value, bool):
        return int(value)
    if isinstance(value, float):
        return f"{value:.6f}"
    return value


def format_line(fmt: str, match: Match) -> str:
    """One result line, ending in a newline: CSV (``CSV_COLUMNS``) or a JSON object (floats to 6 decimals,
    the stamp whole)."""
    if fmt == "csv":
        buf = io.StringIO()
        csv.writer(buf, lineterminator="\n").writerow([_cell(v) for v in match.fields().values()])
        return buf.getvalue()
    fields = {k: round(v, 6) if isinstance(v, float) and k != "stamp" else v for k, v in match.fields().items()}
    return json.dumps(fields) + "\n"


def header(fmt: str) -> str:
    """What a log starts with: the CSV header line, nothing for JSON lines."""
    return ",".join(CSV_COLUMNS) + "\n" if fmt == "csv" else ""


def _trim_to_whole_lines(fd: int) -> int:
    """Cut the file open at ``fd`` after its last newline (a line cut short by a full disk or a power cut);
    returns the size kept."""
    size = os.fstat(fd).st_size
    pos = size
    while pos > 0:
        start = max(0, pos - 65536)
        chunk = os.pread(fd, pos - start, start)
        nl = chunk.rfind(b"\n")
        if nl >= 0:
            keep = start + nl + 1
            break
        pos = start
    else:
        keep = 0
    if keep != size:
        os.ftruncate(fd, keep)
    return keep


def recover(part: Path, target: Path) -> str | None:
    """A dead run's log (``part.Recover``): cut to whole lines and made ``target``; None if nothing whole."""
    with contextlib.closing(Fd(os.open(part, os.O_RDWR))) as rw:   # O_APPEND's descriptor cannot pread
        kept = _trim_to_whole_lines(rw.fd)
    if not kept:
        return None
    os.replace(part, target)
    return f"kept as {target} ({kept} bytes of whole lines)"


class ResultLog:
    """``ResultSink`` writing the result lines (``fmt``: csv or jsonl) to ``out`` (None: standard output; a
    special file such as ``/dev/stdout``: written in place), as the module says. ``lines``: lines written.
    Opening claims the log (``claim``), so construct it once the stream is ready, after every check."""

    def __init__(self, fmt: str, out: Path | None = None, clock=time.monotonic) -> None:
        if fmt not in FORMATS:
            raise ValueError(f"unknown results format {fmt!r} (one of {', '.join(FORMATS)})")
        self.fmt = fmt
        self.where = str(out) if out is not None else "stdout"
        self.lines = 0
        self.target: Path | None = None      # the file the log becomes
        self.part: Path | None = None        # the log while the stream runs
        self._clock = clock
        self._synced = clock()
        self._closed = False
        self.failed = False                  # closed after a failure: the lines stay in ``part``
        self._fd: int | None = None
        self._stream: IO[str] | None = None
        self._was: os.stat_result | None = None
        if out is None:
            self._stream = sys.stdout
        elif is_special(out):
            with writing(self.where):
                self._stream = open(out, "w", newline="")
        else:
            self.target, self._was, self.part, self._fd = open_output(out, recover)

    @property
    def had_older(self) -> bool:
        """A file of the log's name was there when the run began."""
        return self._was is not None

    @property
    def kept(self) -> str:
        """Where the lines are once the stream has ended: the file's name (``NAME.part`` after a failure), or
        ``stdout``."""
        if self.target is None:
            return self.where
        return str(self.part if self.failed else self.target)

    def write(self, match: Match, frame: Frame | None = None) -> None:
        """Write ``match``'s line (after the header, for the first) and hand it to the system."""
        text = (header(self.fmt) if self.lines == 0 else "") + format_line(self.fmt, match)
        with writing(self.where):
            if self._fd is not None:
                data = text.encode("utf-8")
                while data:
                    data = data[os.write(self._fd, data):]
                now = self._clock()
                if now - self._synced >= SYNC_INTERVAL_S:
                    os.fsync(self._fd)
                    self._synced = now
            else:
                assert self._stream is not None
                try:
                    self._stream.write(text)
                    self._stream.flush()
                except OSError:
                    self._drop_stream()
                    raise
        self.lines += 1

    def _drop_stream(self) -> None:
        """After a failed write: point the stream's descriptor at /dev/null, so that the text left in its
        buffer is not tried again at exit (a second error, Python's exit code 120), nor after a closed pipe."""
        with contextlib.suppress(OSError, ValueError, AttributeError):
            assert self._stream is not None
            os.dup2(os.open(os.devnull, os.O_WRONLY), self._stream.fileno())

    def close(self, complete: bool = True, failed: bool = False) -> None:
        """End the log: a file's log is synced, cut to whole lines and renamed to its name, whether the stream
        ended (``complete``) or was stopped early; after a failure (``failed``) it stays ``NAME.part`` beside
        an older ``NAME`` (best effort: the disk may be full); with no line written the log is removed and
        nothing replaced. Standard output is flushed and left open. Idempotent."""
        if self._closed:
            return
        self._closed = True
        if self._fd is None:
            if self._stream is not None and self._stream is not sys.stdout:
                with writing(self.where):
                    self._stream.close()
            return
        assert self.part is not None and self.target is not None
        try:
            if self.lines == 0:
                self.part.unlink(missing_ok=True)
                return
            if failed:
                self.failed = True
                with contextlib.suppress(OSError), contextlib.closing(Fd(os.open(self.part, os.O_RDWR))) as rw:
                    _trim_to_whole_lines(rw.fd)
                    os.fsync(rw.fd)
                return
            with writing(self.where):
                with contextlib.closing(Fd(os.open(self.part, os.O_RDWR))) as rw:
                    _trim_to_whole_lines(rw.fd)
                    os.fsync(rw.fd)
                adopt_mode(self.part, self._was)
                os.replace(self.part, self.target)
        finally:
            os.close(self._fd)     # releases the lock, after the rename
            self._fd = None
