"""``.npz`` arrays plus a JSON metadata entry (kind, schema version): written atomically, read without pickle,
optionally memory-mapped; a foreign, corrupt or newer file refused in one line."""
from __future__ import annotations

import io
import json
import os
import struct
import zipfile
from pathlib import Path

import numpy as np

from vpr_edge.errors import VprError
from vpr_edge.files.atomic import atomic_output


META_KEY = "__meta__"


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
