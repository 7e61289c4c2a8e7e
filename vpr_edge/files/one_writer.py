"""The one-writer lock of an output: an OS file lock beside it, so that two vpr-edge processes never write
one file at once (a writer that dies releases it)."""
from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

from vpr_edge.errors import VprError, warn
from vpr_edge.files.checks import output_target
from vpr_edge.files.temps import lock_path


@contextlib.contextmanager
def writer_lock(path: str | os.PathLike[str], wait: bool = True) -> Iterator[None]:
    """Hold the one-writer lock of ``path``: an OS file lock on ``.NAME.lock`` beside its target, which holds
    the holder's PID (for messages) and is removed when the block ends. The kernel releases the lock when
    its holder dies, so a writer killed by SIGKILL or a power cut never leaves it held (its file stays, and
    the next writer takes it). A second writer waits, saying so once on stderr, or with ``wait`` False is
    refused (VprError, one line). Readers take no lock: they read the previous complete file until the
    writer's rename."""
    import fcntl

    target = output_target(path)
    lock = lock_path(target)
    said = False
    while True:
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
        except OSError as e:
            raise VprError(f"{path}: cannot create its lock file {lock.name} ({e.strerror or e})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
            by = f" (process {holder})" if holder.isdigit() else ""
            if not wait:
                os.close(fd)
                raise VprError(f"{path}: another vpr-edge is writing it{by}; not written twice at once "
                               f"(wait for it, or write another file)") from None
            if not said:
                warn(f"{path}: another vpr-edge is writing it{by}; waiting for it to finish")
                said = True
            fcntl.flock(fd, fcntl.LOCK_EX)
        try:
            current = os.stat(lock)
        except FileNotFoundError:
            current = None
        if current is not None and os.path.samestat(current, os.fstat(fd)):
            break
        os.close(fd)   # the holder before removed that file when it let go: lock the one there now
    try:
        with contextlib.suppress(OSError):
            os.ftruncate(fd, 0)
            os.pwrite(fd, str(os.getpid()).encode(), 0)
        yield
    finally:
        with contextlib.suppress(OSError):
            os.unlink(lock)   # while held: a writer waiting on this file finds it gone and takes a new one
        os.close(fd)   # releases the lock
