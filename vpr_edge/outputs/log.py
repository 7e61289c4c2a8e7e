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
import stat
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import IO

from vpr_edge.api import FIELDS, Match
from vpr_edge.errors import InputError, VprError, warn
from vpr_edge.files import adopt_mode, is_special, output_target
from vpr_edge.frames.frame import Frame

FORMATS = ("csv", "jsonl")
SUFFIX_FORMATS = {".csv": "csv", ".jsonl": "jsonl", ".json": "jsonl"}   # --out's suffix -> format
PART_SUFFIX = ".part"     # NAME.part: the log while its stream runs
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


def part_path(target: Path) -> Path:
    """Where the log of ``target`` is while its stream runs: ``NAME.part`` beside it."""
    return target.with_name(target.name + PART_SUFFIX)


@contextlib.contextmanager
def writing(where: str) -> Iterator[None]:
    """A failed write (disk full, device gone) becomes one line naming ``where``; a closed pipe passes."""
    try:
        yield
    except BrokenPipeError:
        raise
    except OSError as e:
        raise VprError(f"{where}: cannot write results ({e.strerror or e})") from None


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


def claim(target: Path) -> tuple[Path, int]:
    """Open ``target``'s log (``part_path``) for writing, holding its lock; returns it and its descriptor.
    VprError (one line) when another process holds it. A log left by a run that died (the file is there,
    nobody holds its lock) is made ``target`` first, its last partial line cut, and said."""
    import fcntl

    part = part_path(target)
    for _ in range(5):
        try:
            fd = os.open(part, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o666)
        except OSError as e:
            raise VprError(f"{target}: cannot create its log {part.name} ({e.strerror or e})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise InputError("{target}: another vpr-edge is writing it (its log {part} is held); give this run "
                             "another {opt.out}", target=target, part=part.name) from None
        try:
            same = os.path.samestat(os.fstat(fd), os.stat(part))
        except FileNotFoundError:
            same = False
        if not same:            # renamed or removed between our open and our lock: open the new one
            os.close(fd)
            continue
        if os.fstat(fd).st_size == 0:
            return part, fd
        with contextlib.closing(_Fd(os.open(part, os.O_RDWR))) as rw:   # O_APPEND's descriptor cannot pread
            kept = _trim_to_whole_lines(rw.fd)
        if kept:
            os.replace(part, target)
            warn(f"{part}: the log of a run that ended without closing it (killed, power cut); kept as {target} "
                 f"({kept} bytes of whole lines), replaced when this run ends")
        else:
            part.unlink()
        os.close(fd)
    raise VprError(f"{target}: its log {part.name} keeps changing under this run; is another writer at work?")


class _Fd:
    def __init__(self, fd: int) -> None:
        self.fd = fd

    def close(self) -> None:
        os.close(self.fd)


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
            self.target = output_target(out)
            self._was = self.target.stat() if self.target.is_file() else None
            if self._was is not None and not os.access(self.target, os.W_OK):
                raise VprError(f"{out}: write-protected (mode {stat.S_IMODE(self._was.st_mode):04o}); not replaced")
            self.part, self._fd = claim(self.target)

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
                with contextlib.suppress(OSError), contextlib.closing(_Fd(os.open(self.part, os.O_RDWR))) as rw:
                    _trim_to_whole_lines(rw.fd)
                    os.fsync(rw.fd)
                return
            with writing(self.where):
                with contextlib.closing(_Fd(os.open(self.part, os.O_RDWR))) as rw:
                    _trim_to_whole_lines(rw.fd)
                    os.fsync(rw.fd)
                adopt_mode(self.part, self._was)
                os.replace(self.part, self.target)
        finally:
            os.close(self._fd)     # releases the lock, after the rename
            self._fd = None
