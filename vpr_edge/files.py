"""Files, safely: outputs checked before the work and written to a temporary file then renamed; ``.npz``
arrays plus a JSON metadata entry (kind, schema version), read without pickle, optionally memory-mapped."""
from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import stat
import struct
import tempfile
import zipfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from vpr_edge.errors import VprError, warn

META_KEY = "__meta__"


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


TEMP_SUFFIX = ".tmp"


def _alive(pid: int) -> bool:
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
    """The one-writer lock file of ``target`` (``writer_lock``): ``.STEM.lock`` beside it."""
    return target.parent / f".{temp_stem(target)}.lock"


def dead_writers_files(target: Path) -> list[Path]:
    """What writers of ``target`` that died left beside it, without removing it: their temporary files
    (``dead_temps``) and a one-writer lock file nobody holds (``writer_lock``)."""
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


def write_npz(path: str | os.PathLike[str], arrays: dict[str, np.ndarray], meta: dict) -> None:
    """Write ``arrays`` and JSON ``meta`` to ``path`` atomically: a temp file in the same folder, then rename.

    An interrupted or failed write leaves any previous file at ``path`` untouched and no partial file behind.
    """
    path = Path(path)
    if META_KEY in arrays:
        raise ValueError(f"array name {META_KEY} is reserved")
    payload = {k: np.asarray(v) for k, v in arrays.items()}
    if any(a.dtype == object for a in payload.values()):
        raise ValueError("object arrays cannot be stored without pickle")
    payload[META_KEY] = np.array(json.dumps(meta, sort_keys=True))
    with atomic_output(path) as tmp, open(tmp, "wb") as f:
        np.savez(f, **payload)


def _mapped_members(path: Path, z: zipfile.ZipFile) -> dict[str, np.ndarray]:
    """Every stored (uncompressed) ``.npy`` member of an open archive as a read-only np.memmap into the file:
    opening costs the headers only, and the pages of an array are read when touched. Small members (the
    metadata) are read whole. Raises ValueError for a compressed member or a pickled (object) array."""
    out: dict[str, np.ndarray] = {}
    with open(path, "rb") as f:
        for info in z.infolist():
            name = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
            if info.file_size < 4096:
                out[name] = np.load(io.BytesIO(z.read(info)), allow_pickle=False)
                continue
            if info.compress_type != zipfile.ZIP_STORED:
                raise ValueError(f"member {name} is compressed and cannot be memory-mapped")
            f.seek(info.header_offset)
            local = f.read(30)
            if local[:4] != b"PK\x03\x04":
                raise zipfile.BadZipFile(f"bad local header for {name}")
            name_len, extra_len = struct.unpack("<HH", local[26:30])
            f.seek(info.header_offset + 30 + name_len + extra_len)
            version = np.lib.format.read_magic(f)
            read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else \
                np.lib.format.read_array_header_2_0
            shape, fortran, dtype = read_header(f)
            if dtype.hasobject:
                raise ValueError("Object arrays cannot be loaded when allow_pickle=False")
            out[name] = np.memmap(path, dtype=dtype, mode="r", offset=f.tell(), shape=shape,
                                  order="F" if fortran else "C")
    return out


def read_npz(path: str | os.PathLike[str], kind: str, schema: int | tuple[int, ...], mmap: bool = False
             ) -> tuple[dict[str, np.ndarray], dict]:
    """Read a file written by :func:`write_npz`; check its ``kind`` and ``schema`` version (one, or the
    versions this release reads). With ``mmap``, large arrays come back memory-mapped (read-only), so that
    opening a large map reads its headers and metadata only.

    Raises VprError with a one-line reason naming ``path`` for a missing, corrupt or foreign file.
    """
    path = Path(path)
    if not path.is_file():
        raise VprError(f"{path}: no such file" if not path.exists() else f"{path}: not a vpr-edge {kind} (not a file)")
    try:
        with open(path, "rb") as f:
            head = f.read(4)
    except OSError as e:
        raise VprError(f"{path}: cannot read ({e.strerror or e})") from None
    if head != b"PK\x03\x04":
        raise VprError(f"{path}: not a vpr-edge {kind} ({_describe(head, path)}; expected an .npz archive)")
    try:
        with zipfile.ZipFile(path) as z:
            _check_members(path, z, kind)
        if mmap:
            with zipfile.ZipFile(path) as z:
                arrays = _mapped_members(path, z)
        else:
            with np.load(path, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
    except ValueError as e:
        if "pickle" in str(e):
            raise VprError(f"{path}: not a vpr-edge {kind} (holds pickled objects, which vpr-edge never "
                           f"loads)") from None
        raise VprError(f"{path}: not a vpr-edge {kind} (corrupt archive: {str(e).splitlines()[0][:80]})") from None
    except (zipfile.BadZipFile, OSError, EOFError, NotImplementedError, RuntimeError) as e:
        # damaged flag bits read as encryption or features zipfile does not implement: corrupt here too
        raise VprError(f"{path}: not a vpr-edge {kind} (truncated or corrupt archive: "
                       f"{str(e).splitlines()[0][:80]})") from None
    if META_KEY not in arrays:
        raise VprError(f"{path}: not a vpr-edge {kind} (an .npz archive without vpr-edge metadata)")
    try:
        meta = json.loads(str(arrays.pop(META_KEY)))
    except json.JSONDecodeError as e:
        raise VprError(f"{path}: corrupt metadata ({e})") from None
    if not isinstance(meta, dict):
        raise VprError(f"{path}: corrupt metadata (a JSON {type(meta).__name__}, expected an object)")
    if meta.get("kind") != kind:
        raise VprError(f"{path}: not a vpr-edge {kind} (it is a vpr-edge {meta.get('kind')})")
    readable = (schema,) if isinstance(schema, int) else tuple(schema)
    if meta.get("schema") not in readable:
        raise VprError(newer_schema(path, kind, meta.get("schema"), readable) or
                       f"{path}: {kind} schema version {meta.get('schema')} is not supported "
                       f"(this vpr-edge reads version {', '.join(map(str, readable))}); rebuild it")
    return arrays, meta


def newer_schema(path: str | os.PathLike[str], kind: str, found: object, readable: tuple[int, ...]) -> str | None:
    """The line for a file of ``kind`` whose schema version ``found`` is newer than any this vpr-edge reads
    (``readable``): it was made by a newer vpr-edge, which reads it; None for any other version."""
    if isinstance(found, int) and not isinstance(found, bool) and found > max(readable):
        return (f"{path}: made by a newer vpr-edge ({kind} schema {found}, this one reads up to "
                f"{max(readable)}): upgrade vpr-edge")
    return None


def _check_members(path: Path, z: zipfile.ZipFile, kind: str) -> None:
    """VprError for an archive that could make the reader allocate beyond the file's size: a compressed
    member (vpr-edge never compresses) or members declaring more bytes than the file holds."""
    size = path.stat().st_size
    for info in z.infolist():
        if info.compress_type != zipfile.ZIP_STORED:
            raise VprError(f"{path}: not a vpr-edge {kind} (member {info.filename} is compressed; vpr-edge "
                           f"writes stored members only)")
    if sum(info.file_size for info in z.infolist()) > size:
        raise VprError(f"{path}: not a vpr-edge {kind} (its members declare more bytes than the file holds)")


def _describe(head: bytes, path: Path) -> str:
    """A guess at what a foreign file is, from its first bytes, for error messages."""
    if not head:
        return "empty file"
    if head.startswith(b"\x93NUM"):
        return "a single .npy array"
    if path.suffix.lower() == ".onnx" or head[:1] == b"\x08":
        return "looks like an ONNX model"
    if all(32 <= c < 127 or c in (9, 10, 13) for c in head):
        return "a text file"
    return "unknown binary format"


def read_csv_rows(path: str | os.PathLike[str], what: str) -> list[tuple[int, list[str]]]:
    """Every row of a CSV file (the header first) with its line number, as spreadsheets write them: UTF-8
    with or without a byte-order mark, LF or CRLF line ends, blank lines skipped (a row of empty cells,
    ``,,``, is kept: the reader says what it means). VprError ``path: cannot read WHAT (reason)`` for a
    missing, unreadable or non-text file."""
    import csv

    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            reader = csv.reader(f)
            return [(reader.line_num, row) for row in reader if row]
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        raise VprError(f"{path}: cannot read {what} ({getattr(e, 'strerror', None) or e})") from None


def file_sha256(path: str | os.PathLike[str]) -> str:
    """Hex SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()
