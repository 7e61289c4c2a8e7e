"""Atomic writing: an output written to a temporary file beside it, then renamed over it with the replaced
file's mode and owner, so that a reader never sees a partial file."""
from __future__ import annotations

import contextlib
import os
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path

from vpr_edge.errors import VprError, warn
from vpr_edge.files.checks import check_writable, is_special, output_target
from vpr_edge.files.temps import TEMP_SUFFIX, remove_stale_temps, temp_stem


def adopt_mode(new: str | os.PathLike[str], was: os.stat_result | None) -> None:
    """Give ``new``, about to be renamed over a file whose status was ``was``, that file's mode and, where
    allowed, its owner; a new file (``was`` None) the umask's mode."""
    if was is not None:
        os.chmod(new, stat.S_IMODE(was.st_mode))
        with contextlib.suppress(OSError):
            os.chown(new, was.st_uid, was.st_gid)
    else:
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(new, 0o666 & ~umask)


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (beside its target, for a symbolic link); when the block ends
    without error, fsync it, give it the replaced file's mode and owner (a new file: the umask's mode) and
    rename it over the target; a target this user may not write is refused first, as ``cp`` refuses it. On
    error, Ctrl-C or SIGTERM the temporary file is removed and the target is left as it was; the temporary
    files of writers that died are removed first (and said). A special file (``/dev/stdout``) is yielded as it
    is, written in place. An OSError without a file name (a full disk mid-write) is given ``path``'s name."""
    path = Path(path)
    if is_special(path):
        yield path
        return
    check_writable(path)
    target = output_target(path)
    was = target.stat() if target.is_file() else None
    if was is not None and not os.access(target, os.W_OK):
        raise VprError(f"{path}: write-protected (mode {stat.S_IMODE(was.st_mode):04o}); not replaced")
    stale = remove_stale_temps(target)
    if stale:
        warn(f"{target}: removed {len(stale)} temporary file(s) left by writers that died (e.g. {stale[0].name})")
    fd, tmp = tempfile.mkstemp(prefix=f".{temp_stem(target)}.{os.getpid()}.", suffix=TEMP_SUFFIX,
                               dir=target.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        adopt_mode(tmp, was)
        os.replace(tmp, target)
    except OSError as e:
        Path(tmp).unlink(missing_ok=True)
        if e.filename is None or str(e.filename) == tmp:
            raise OSError(e.errno, e.strerror or str(e), str(path)) from None
        raise
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
