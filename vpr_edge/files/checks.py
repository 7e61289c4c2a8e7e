"""Outputs checked before the work: a path that can be written as a file (special files: this process's own
streams and ``/dev/null`` only), a symbolic link's target, no output over an input or another output."""
from __future__ import annotations

import os
import stat
import tempfile
from pathlib import Path

from vpr_edge.errors import VprError
from vpr_edge.files.temps import temp_stem


def is_special(path: str | os.PathLike[str]) -> bool:
    """True for an existing character device, pipe or socket (``/dev/stdout``, ``/dev/null``, a FIFO): an
    output written in place, never renamed over."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return False
    return stat.S_ISCHR(mode) or stat.S_ISFIFO(mode) or stat.S_ISSOCK(mode)


def output_target(path: str | os.PathLike[str]) -> Path:
    """Where writing ``path`` lands: a symbolic link is followed to its final target, which is replaced while
    the link stays (the link's own folder need not be writable, the target's must)."""
    p = Path(path)
    if not p.is_symlink():
        return p
    target = Path(os.path.realpath(p))
    if target.is_symlink():   # realpath stops inside a loop of links
        raise VprError(f"{path}: a loop of symbolic links; name a file")
    return target


def _own_stream(path: str | os.PathLike[str]) -> bool:
    """True for this process's own standard streams and descriptors (``/dev/stdout``, ``/dev/stderr``,
    ``/dev/fd/N``, ``/proc/self/fd/N``) and ``/dev/null``: the special files an output may name."""
    text = os.path.abspath(os.fspath(path))
    return text in ("/dev/stdout", "/dev/stderr", "/dev/null") or \
        text.startswith(("/dev/fd/", "/proc/self/fd/", f"/proc/{os.getpid()}/fd/"))


def check_writable(path: str | os.PathLike[str]) -> None:
    """Raise VprError unless ``path`` can be written as a file: its folder exists and is writable, and it
    is not itself a folder (a symbolic link: its target's). Of the special files (``is_special``) only this
    process's own streams and ``/dev/null`` are outputs (written in place); another FIFO, socket or device
    is refused at once (opening a FIFO nobody reads would wait for ever). Called before any work, so that
    bad output paths fail at once."""
    if is_special(path):
        if not _own_stream(path):
            raise VprError(f"{path}: a FIFO, socket or device, not a file to write (name a file, or /dev/stdout)")
        if not os.access(path, os.W_OK):
            raise VprError(f"{path}: not writable")
        return
    path = output_target(path)
    folder = path.parent
    if path.is_dir():
        raise VprError(f"{path}: is a folder, expected a file name to write")
    if not folder.is_dir():
        raise VprError(f"{path}: folder {folder} does not exist")
    if path.exists() and not path.is_file():
        raise VprError(f"{path}: is not a regular file, expected a file name to write")
    try:  # os.access is not enough: root passes it on read-only and virtual file systems
        fd, probe = tempfile.mkstemp(prefix=f".{temp_stem(path)}.", suffix=".probe", dir=folder)
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        raise VprError(f"{path}: folder {folder} is not writable ({e.strerror or e})") from None


def output_path(text: str) -> Path:
    """A command-line output path: a trailing slash names a folder, which is refused (an output is a file)."""
    if text.endswith(("/", os.sep)) or Path(text).is_dir():
        raise VprError(f"{text}: is a folder, expected a file name to write")
    return Path(text)


def check_not_input(outputs: dict[str, str | os.PathLike[str] | None],
                    inputs: list[str | os.PathLike[str] | None]) -> None:
    """Refuse (VprError, before any work) an output that is one of the command's inputs or lies inside an
    input folder, following symbolic links, and two outputs naming one file. ``outputs``: option -> path."""
    def real(p: str | os.PathLike[str]) -> Path:
        return Path(os.path.realpath(p))

    def same(a: Path, b: Path) -> bool:   # one file under two names: a hard link
        try:
            return os.path.samefile(a, b)
        except OSError:
            return False

    given = {opt: p for opt, p in outputs.items() if p is not None and not is_special(p)}
    sources = [(p, real(p)) for p in inputs if p is not None and "://" not in str(p)]
    seen: dict[Path, str] = {}
    for opt, out in given.items():
        target = real(out)
        if target in seen:
            raise VprError(f"{out}: {seen[target]} and {opt} name the same file; give each its own")
        seen[target] = opt
        for inp, source in sources:
            if target == source or same(target, source):
                raise VprError(f"{out}: {opt} would write over an input of this command ({inp}); "
                               f"write it elsewhere")
            if source.is_dir() and source in target.parents:
                raise VprError(f"{out}: {opt} lies inside the input folder {inp}; write it elsewhere")
