"""Array files: ``.npz`` arrays plus a JSON metadata entry, written atomically, read without pickle."""
from __future__ import annotations

import contextlib
import hashlib
import io
import json
import mmap as mmap_module
import os
import struct
import tempfile
import threading
import weakref
import zipfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from vpr_edge.errors import VprError

META_KEY = "__meta__"


def check_writable(path: str | os.PathLike[str]) -> None:
    """Raise VprError unless ``path`` can be written as a file: its folder exists and is writable, and it
    is not itself a folder. Called before any work, so that bad output paths fail at once."""
    path = Path(path)
    folder = path.parent
    if path.is_dir():
        raise VprError(f"{path}: is a folder, expected a file name to write")
    if not folder.is_dir():
        raise VprError(f"{path}: folder {folder} does not exist")
    if path.exists() and not path.is_file():
        raise VprError(f"{path}: is not a regular file, expected a file name to write")
    try:  # os.access is not enough: root passes it on read-only and virtual file systems
        fd, probe = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".probe", dir=folder)
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        raise VprError(f"{path}: folder {folder} is not writable ({e.strerror or e})") from None


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; when the block ends without error, fsync it, give it the
    umask's mode and rename it over ``path``. On error the temporary file is removed and ``path`` is left
    as it was."""
    path = Path(path)
    check_writable(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


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


def _mapping_of(arr: np.ndarray) -> mmap_module.mmap | None:
    """The mmap object behind a memory-mapped array or a view of one (None for an array in RAM)."""
    base = arr
    while base is not None and not isinstance(getattr(base, "_mmap", None), mmap_module.mmap):
        base = getattr(base, "base", None)
    return None if base is None else base._mmap


def release_pages(arr: np.ndarray) -> bool:
    """Drop the pages of a memory-mapped array, or of a view of one (a block of rows), from this process
    (``madvise(MADV_DONTNEED)`` on the pages the view spans): a pass over a large map would otherwise leave
    every page it read counted in the process's RSS. The data stay in the file (and the OS page cache) and
    are read again when next touched. Returns False (nothing done) for an array in RAM or where the OS has
    no such call."""
    mapping = _mapping_of(arr)
    dontneed = getattr(mmap_module, "MADV_DONTNEED", None)
    if mapping is None or dontneed is None or arr.size == 0:
        return False
    origin = np.frombuffer(mapping, np.uint8).ctypes.data          # the mapping's first byte
    lo = arr.ctypes.data - origin
    hi = lo + arr.size * arr.itemsize if arr.flags.c_contiguous else len(mapping)
    lo = lo - lo % mmap_module.PAGESIZE if arr.flags.c_contiguous else 0
    mapping.madvise(dontneed, lo, min(len(mapping), hi) - lo)
    return True


class RowReader:
    """Rows of a memory-mapped (R, D) array read with ``pread`` instead of through the mapping, kept in a
    bounded cache (first in, first out; ``cache_bytes``, at least ``min_rows`` rows).

    Scattered reads through a mapping (a local window, a probe sample, a coarse search's candidates) leave
    the pages they touch mapped, and this kernel maps page-cache pages in large folios: ~1,500 rows read at
    random mapped 96 MB of a 205 MB map (README, "Matchers at scale"). Read this way, the process holds the
    cache and nothing else; the file's pages are the OS page cache's. Thread-safe."""

    def __init__(self, arr: np.memmap, cache_bytes: int = 16 << 20, min_rows: int = 1024) -> None:
        if arr.ndim != 2 or not arr.flags.c_contiguous:
            raise ValueError("RowReader needs a C-contiguous 2-D memory-mapped array")
        self.shape, self.dtype = arr.shape, arr.dtype
        self.row_bytes = int(arr.shape[1] * arr.dtype.itemsize)
        self.path, self.offset = str(arr.filename), int(arr.offset)
        self._fd = os.open(self.path, os.O_RDONLY)
        weakref.finalize(self, os.close, self._fd)
        cap = min(arr.shape[0], max(min_rows, cache_bytes // max(1, self.row_bytes)))
        self._buf = np.empty((max(cap, 1), arr.shape[1]), arr.dtype)
        self._owner = np.full(len(self._buf), -1, np.int64)     # cache slot -> row
        self._slot = np.full(arr.shape[0], -1, np.int32)        # row -> cache slot
        self._next = 0
        self._lock = threading.Lock()

    def _read(self, rows: np.ndarray) -> np.ndarray:
        """Sorted unique rows (n,) -> (n, D), one ``preadv`` per run of consecutive rows."""
        out = np.empty((len(rows), self.shape[1]), self.dtype)
        cut = np.flatnonzero(np.diff(rows) != 1) + 1
        for a, b in zip(np.r_[0, cut], np.r_[cut, len(rows)]):
            want = int(b - a) * self.row_bytes
            at = self.offset + int(rows[a]) * self.row_bytes
            got = os.preadv(self._fd, [memoryview(out[a:b]).cast("B")], at)
            if got != want:
                raise OSError(f"{self.path}: short read ({got} of {want} bytes): the file changed or is truncated")
        return out

    def _keep(self, rows: np.ndarray, values: np.ndarray) -> None:
        """Put rows (n <= cache size) into the cache, evicting the oldest."""
        at = (self._next + np.arange(len(rows))) % len(self._buf)
        old = self._owner[at]
        self._slot[old[old >= 0]] = -1
        self._owner[at], self._slot[rows], self._buf[at] = rows, at, values
        self._next = int(at[-1] + 1) % len(self._buf)

    def take(self, idx: np.ndarray) -> np.ndarray:
        """Rows ``idx`` (n,) int, any order, repeats allowed -> (n, D) copies."""
        idx = np.asarray(idx, np.int64).reshape(-1)
        if idx.size and (idx.min() < -self.shape[0] or idx.max() >= self.shape[0]):
            raise IndexError(f"row index out of range for {self.shape[0]} rows")
        idx = np.where(idx < 0, idx + self.shape[0], idx)
        with self._lock:
            slots = self._slot[idx]
            hit = slots >= 0
            out = np.empty((len(idx), self.shape[1]), self.dtype)
            out[hit] = self._buf[slots[hit]]
            if not hit.all():
                need, inverse = np.unique(idx[~hit], return_inverse=True)
                values = self._read(need)
                out[~hit] = values[inverse]
                if len(need) <= len(self._buf):
                    self._keep(need, values)
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
    except (zipfile.BadZipFile, OSError, EOFError) as e:
        raise VprError(f"{path}: not a vpr-edge {kind} (truncated or corrupt archive: "
                       f"{str(e).splitlines()[0][:80]})") from None
    if META_KEY not in arrays:
        raise VprError(f"{path}: not a vpr-edge {kind} (an .npz archive without vpr-edge metadata)")
    try:
        meta = json.loads(str(arrays.pop(META_KEY)))
    except json.JSONDecodeError as e:
        raise VprError(f"{path}: corrupt metadata ({e})") from None
    if meta.get("kind") != kind:
        raise VprError(f"{path}: not a vpr-edge {kind} (it is a vpr-edge {meta.get('kind')})")
    readable = (schema,) if isinstance(schema, int) else tuple(schema)
    if meta.get("schema") not in readable:
        raise VprError(f"{path}: {kind} schema version {meta.get('schema')} is not supported "
                       f"(this vpr-edge reads version {', '.join(map(str, readable))}); rebuild it")
    return arrays, meta


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


def file_sha256(path: str | os.PathLike[str]) -> str:
    """Hex SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()
