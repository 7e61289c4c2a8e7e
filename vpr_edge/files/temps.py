"""What writers leave beside an output: the names of their temporary files (``.STEM.PID.XXXXXXXX.tmp``) and
of the one-writer lock file (``.STEM.lock``), and those left by writers that died."""
from __future__ import annotations

import os
from pathlib import Path


TEMP_SUFFIX = ".tmp"


def _alive(pid: int) -> bool:
    """True while process ``pid`` runs (another user's included)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:   # another user's process
        return True
    return True


NAME_MAX = 255   # bytes in one file name (ext4, xfs, btrfs, tmpfs)


def temp_stem(target: Path) -> str:
    """The part of ``target``'s name its temporary files carry (``.STEM.PID.XXXXXXXX.tmp``): the name,
    cut by whole characters so that the temporary name stays within ``NAME_MAX``
    whatever the target's length."""
    room = NAME_MAX - len(f"...{2**32}.xxxxxxxx{TEMP_SUFFIX}")   # dots, the widest PID, mkstemp's 8 characters
    stem = target.name
    while len(os.fsencode(stem)) > room:   # whole characters only
        stem = stem[:-1]
    return stem


def remove_stale_temps(target: Path) -> list[Path]:
    """Remove the temporary files that writers of ``target`` which have died (killed, power lost) left beside
    it: ``.STEM.PID.*.tmp`` (``temp_stem``) whose PID is no longer running. Returns what was removed."""
    removed = dead_temps(target)
    for tmp in removed:
        tmp.unlink(missing_ok=True)
    return removed


def dead_temps(target: Path) -> list[Path]:
    """The temporary files beside ``target`` of its writers that have died: ``.STEM.PID.*.tmp``
    (``temp_stem``) whose PID is no longer running."""
    stem = temp_stem(target)
    dead = []
    for tmp in target.parent.glob(f".{glob_escape(stem)}.*{TEMP_SUFFIX}"):
        pid = tmp.name[len(stem) + 2:].split(".", 1)[0]
        if pid.isdigit() and int(pid) != os.getpid() and not _alive(int(pid)):
            dead.append(tmp)
    return dead


def lock_path(target: Path) -> Path:
    """The one-writer lock file of ``target`` (``one_writer.writer_lock``): ``.STEM.lock`` beside it."""
    return target.parent / f".{temp_stem(target)}.lock"


def dead_writers_files(target: Path) -> list[Path]:
    """What writers of ``target`` that died left beside it, without removing it: their temporary files
    (``dead_temps``) and a one-writer lock file nobody holds (``one_writer.writer_lock``)."""
    import fcntl

    left = dead_temps(target)
    lock = lock_path(target)
    try:
        fd = os.open(lock, os.O_RDONLY)
    except OSError:
        return left
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)   # taken: nobody writes it now
        left.append(lock)
    except OSError:
        pass
    finally:
        os.close(fd)   # releases it
    return left


def glob_escape(name: str) -> str:
    """``name`` with glob's special characters escaped."""
    return "".join(f"[{c}]" if c in "*?[" else c for c in name)
