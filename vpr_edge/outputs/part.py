"""An output written as the stream goes: ``NAME.part`` while the stream runs, ``NAME`` when it ends.

Every file output of ``localize`` (the log, an MCAP file, a Rerun recording) is written in place into
``NAME.part`` beside ``NAME``, so that a killed process leaves what it wrote readable. One writer at a time
holds a lock on ``NAME.part``. When the stream ends on its own or by the user's stop, ``NAME.part`` becomes
``NAME`` (``finish``); after a failure it stays, beside an older ``NAME`` left as it was. A ``NAME.part`` that
no process holds was left by a run that died without a word (SIGKILL, a power cut): the next writer of that
name hands it to its output's ``recover`` first (the log cuts it to whole lines, an MCAP file is finalised),
which makes it ``NAME``, and says so."""
from __future__ import annotations

import contextlib
import os
import stat
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

from vpr_edge.errors import InputError, VprError, warn
from vpr_edge.files.atomic import adopt_mode
from vpr_edge.files.checks import output_target

PART_SUFFIX = ".part"     # NAME.part: the output while its stream runs
FLUSH_INTERVAL_S = 1.0    # a recording hands each record to the system within this, seconds, frames or none

# part, target -> what became of the dead run's output (said in a warning), or None when nothing was kept
Recover = Callable[[Path, Path], "str | None"]


@contextlib.contextmanager
def writing(where: str) -> Iterator[None]:
    """A failed write (disk full, device gone) becomes one line naming ``where``; a closed pipe passes."""
    try:
        yield
    except BrokenPipeError:
        raise
    except OSError as e:
        raise VprError(f"{where}: cannot write results ({e.strerror or e})") from None


def part_path(target: Path) -> Path:
    """Where the output ``target`` is while its stream runs: ``NAME.part`` beside it."""
    return target.with_name(target.name + PART_SUFFIX)


class Fd:
    """A descriptor ``contextlib.closing`` can close."""

    def __init__(self, fd: int) -> None:
        self.fd = fd

    def close(self) -> None:
        os.close(self.fd)


def claim(target: Path, recover: Recover) -> tuple[Path, int]:
    """Open ``target``'s ``NAME.part`` for writing (appending), holding its lock; returns it and its
    descriptor. InputError (one line) when another process holds it. A part left by a run that died (the
    file is there and not empty, nobody holds its lock) goes to ``recover`` first, and what it says is
    warned."""
    import fcntl

    part = part_path(target)
    for _ in range(5):
        try:
            fd = os.open(part, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o666)
        except OSError as e:
            raise VprError(f"{target}: cannot create {part.name} ({e.strerror or e})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise InputError("{target}: another vpr-edge is writing it (its {part} is held); give this run "
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
        said = recover(part, target)
        part.unlink(missing_ok=True)
        if said:
            warn(f"{part}: left by a run that ended without closing it (killed, power cut); {said}, replaced "
                 f"when this run ends")
        os.close(fd)
    raise VprError(f"{target}: its {part.name} keeps changing under this run; is another writer at work?")


def open_output(out: Path, recover: Recover) -> tuple[Path, "os.stat_result | None", Path, int]:
    """The file ``out`` names (a link's target), the status of the file there now (None: none), and its
    claimed ``NAME.part`` and descriptor (``claim``). A file there this user may not write is refused first,
    in one line."""
    target = output_target(out)
    was = target.stat() if target.is_file() else None
    if was is not None and not os.access(target, os.W_OK):
        raise VprError(f"{out}: write-protected (mode {stat.S_IMODE(was.st_mode):04o}); not replaced")
    part, fd = claim(target, recover)
    return target, was, part, fd


def finish(part: Path, target: Path, was: os.stat_result | None) -> None:
    """``part``, written and closed by its writer, synced and made ``target`` (with the mode of the file it
    replaces, ``was``)."""
    with contextlib.closing(Fd(os.open(part, os.O_RDONLY))) as f:
        os.fsync(f.fd)
    adopt_mode(part, was)
    os.replace(part, target)


class Flusher:
    """Hands a recording's records to the system (``flush``) within ``FLUSH_INTERVAL_S`` of their writing,
    while frames come or not (a stalled camera): a thread flushes every half interval when ``wrote`` was
    called since, holding ``lock`` (a writer that is not thread-safe holds it too); a failed flush is kept in
    ``error`` for the next write to raise (``check``)."""

    def __init__(self, flush: Callable[[], None], period: float = FLUSH_INTERVAL_S / 2) -> None:
        self.lock = threading.Lock()
        self.error: OSError | None = None
        self._flush, self._period = flush, period
        self._dirty = False
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="vpr-edge-flush", daemon=True)
        self._thread.start()

    def check(self) -> None:
        """Raise a failed flush's error (under ``lock``)."""
        if self.error is not None:
            raise self.error

    def wrote(self) -> None:
        """Records were written (under ``lock``): flushed at the next tick."""
        self._dirty = True

    def _run(self) -> None:
        while not self._stop.wait(self._period):
            with self.lock:
                if self._dirty and self.error is None:
                    self._dirty = False
                    try:
                        self._flush()
                    except OSError as e:
                        self.error = e

    def stop(self) -> None:
        """End the thread (its flush in progress first). Idempotent."""
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join()
