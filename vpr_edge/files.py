"""Files, safely: outputs checked before the work and written to a temporary file then renamed; ``.npz``
arrays plus a JSON metadata entry (kind, schema version), read without pickle, optionally memory-mapped."""
from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import struct
import tempfile
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
