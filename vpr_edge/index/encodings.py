"""Reference encodings as a map stores them: float16, float32, or int8 with one scale per row.

int8 rows hold a quarter of float32's bytes at nearly its accuracy (docs/decisions.md, "Tried and not taken"), so they
are build-map's default. Similarities are
computed from what is stored, a block of references at a time, so that a memory-mapped map is read as it
is used and never expanded whole into RAM.
"""
from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from vpr_edge.index.rows import RowReader, release_pages

DTYPES = {"int8": np.int8, "float16": np.float16, "float32": np.float32}  # storage name -> stored dtype
STORAGES = tuple(DTYPES)
DEFAULT_STORAGE = "int8"   # a quarter of float32's bytes at nearly its accuracy (docs/decisions.md, "Tried and not taken")
BLOCK_BYTES = 2 << 20   # float32 scratch per block of references in ``similarity``: cache-sized blocks ran
                        # faster than large ones (timed on maps of 1,000 to 100,000 places)


def bytes_per_place(dim: int, storage: str) -> int:
    """Bytes a map keeps per reference for ``dim``-dim encodings stored as ``storage`` (int8: one scale of 4
    bytes per row besides the values)."""
    if storage not in STORAGES:
        raise ValueError(f"unknown storage {storage!r}; choose from {', '.join(STORAGES)}")
    return dim * np.dtype(DTYPES[storage]).itemsize + (4 if storage == "int8" else 0)


def quantise_rows(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R, D) float -> (int8 (R, D), scale float32 (R,)) with x ~= q * scale[:, None]: symmetric, max-abs
    over the row, then the scale adjusted so that each dequantised row keeps the original row's L2 norm
    (cosines against unit rows stay cosines). All-zero rows get scale 1."""
    x = np.asarray(x, np.float32)
    peak = np.abs(x).max(axis=1) if x.size else np.zeros(len(x), np.float32)
    step = np.where(peak > 0, peak / 127.0, 1.0).astype(np.float32)
    q = np.clip(np.rint(x / step[:, None]), -127, 127).astype(np.int8)
    qn = np.linalg.norm(q.astype(np.float32), axis=1)
    scale = np.where(qn > 0, np.linalg.norm(x, axis=1) / np.maximum(qn, 1e-30), 1.0).astype(np.float32)
    return q, scale


@dataclass(frozen=True)
class Encodings:
    """``values`` (R, D) of dtype ``storage`` (an array, or a read-only memmap into the map file) and, for
    int8, ``scale`` (R,): reference r is ``values[r] * scale[r]``."""

    values: np.ndarray
    storage: str
    scale: np.ndarray | None = None
    _rows: RowReader | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        # a memory-mapped map: chosen rows are read with pread into a bounded cache, not through the mapping
        if isinstance(self.values, np.memmap) and self.values.ndim == 2 and self.values.flags.c_contiguous:
            object.__setattr__(self, "_rows", RowReader(self.values))

    def take(self, rows: np.ndarray) -> np.ndarray:
        """The stored values of references ``rows`` (n,) int -> (n, D), in the stored dtype."""
        return self._rows.take(rows) if self._rows is not None else np.asarray(self.values[rows])

    @classmethod
    def pack(cls, x: np.ndarray, storage: str) -> "Encodings":
        """Float encodings (R, D) stored as ``storage`` (one of STORAGES)."""
        if storage not in STORAGES:
            raise ValueError(f"unknown storage {storage!r}; choose from {', '.join(STORAGES)}")
        if storage == "int8":
            q, scale = quantise_rows(x)
            return cls(q, storage, scale)
        return cls(np.asarray(x).astype(DTYPES[storage]), storage)

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], storage: str) -> "Encodings":
        """Read back what :meth:`to_arrays` wrote; ValueError if the arrays do not fit ``storage``."""
        values, scale = arrays.get("encodings"), arrays.get("encodings_scale")
        if values is None or values.ndim != 2:
            raise ValueError("no 2-D encodings array")
        if storage not in STORAGES or values.dtype != DTYPES[storage]:
            raise ValueError(f"encodings are {values.dtype}, storage says {storage!r}")
        if storage == "int8" and (scale is None or scale.shape != (len(values),)):
            raise ValueError("int8 encodings without one scale per row")
        if storage == "int8" and not (np.isfinite(scale).all() and (np.asarray(scale) >= 0).all()):
            raise ValueError("int8 row scales hold NaN, infinite or negative values")
        made = cls(values, storage, np.asarray(scale, np.float32) if storage == "int8" else None)
        if storage != "int8" and not all(np.isfinite(block).all() for _, block in made.blocks(8192)):
            raise ValueError("encodings hold NaN or infinite values")
        return made

    def concat(self, more: "Encodings") -> "Encodings":
        """These rows then ``more``'s, in this storage (``more`` repacked if it is stored otherwise): the
        stored values are copied as they are, never expanded to float32 (an appended route)."""
        if more.storage != self.storage:
            more = Encodings.pack(more.dense(), self.storage)
        scale = None if self.scale is None else np.concatenate([self.scale, more.scale])
        return Encodings(np.concatenate([self.values, more.values]), self.storage, scale)

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Arrays for the map file."""
        return {"encodings": self.values} | ({"encodings_scale": self.scale} if self.scale is not None else {})

    @property
    def bytes_per_place(self) -> int:
        """Bytes kept per reference (``bytes_per_place``)."""
        return bytes_per_place(self.shape[1], self.storage)

    @property
    def shape(self) -> tuple[int, int]:
        """(R, D)."""
        return tuple(self.values.shape)  # type: ignore[return-value]

    def dense(self) -> np.ndarray:
        """All references as float32 (R, D) in RAM."""
        out = np.asarray(self.values, np.float32)
        return out * self.scale[:, None] if self.scale is not None else out

    def blocks(self, rows: int) -> Iterator[tuple[int, np.ndarray]]:
        """(first row, stored values (n <= rows, D)) for every ``rows`` references in order: a pass over the
        map; on a memory-mapped map each block's pages are dropped once the caller is done with it, so the
        pass keeps no more than a block mapped."""
        for i in range(0, self.shape[0], rows):
            block = self.values[i:i + rows]
            yield i, block
            release_pages(block)

    def in_order(self, block: int = 4096) -> Iterator[np.ndarray]:
        """The stored values in route order, a block (n <= block, D) at a time (``blocks``). Cosines between
        these rows are the encodings' (an int8 row's scale is positive)."""
        for _, values in self.blocks(block):
            yield values

    def dense_row(self, r: int) -> np.ndarray:
        """Reference ``r`` as float32 (D,)."""
        row = self.take(np.array([r]))[0].astype(np.float32)
        return row * self.scale[r] if self.scale is not None else row

    def similarity(self, queries: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """Queries (B, D) -> dot products with every reference (B, R) float32, or with the references
        ``rows`` (int array) only (B, len(rows)); a block of references at a time (about
        BLOCK_BYTES of float32 scratch), from the stored values."""
        q = np.atleast_2d(np.asarray(queries, np.float32))
        if rows is None and self.storage == "float32" and not isinstance(self.values, np.memmap):
            return q @ self.values.T
        r, d = self.shape
        step = max(1, BLOCK_BYTES // (4 * d))
        picked = None if rows is None else np.asarray(rows, np.int64).reshape(-1)
        n = r if picked is None else len(picked)
        # a block at a time, through one float32 scratch: no float32 copy of many rows (a large fresh
        # allocation stalls), and a pass over a memory-mapped map keeps no more than a block mapped
        blocks = self.blocks(step) if picked is None else \
            ((i, self.take(picked[i:i + step])) for i in range(0, n, step))
        out = np.empty((len(q), n), np.float32)
        scratch = np.empty((min(n, step), d), np.float32)
        for i, block in blocks:
            np.copyto(scratch[:len(block)], block, casting="unsafe")
            out[:, i:i + len(block)] = q @ scratch[:len(block)].T
        if self.scale is not None:
            out *= self.scale if picked is None else self.scale[picked]
        return out


class EncodingWriter:
    """Encodings of R references filled in as they are computed, any rows at a time, each batch packed into
    ``storage`` at once (int8 scales are per row, so packing by batch equals packing all together). Holds
    the stored bytes only, plus a float32 copy when ``keep_float`` (to train classifiers on)."""

    def __init__(self, n: int, dim: int, storage: str, keep_float: bool = False) -> None:
        if storage not in STORAGES:
            raise ValueError(f"unknown storage {storage!r}; choose from {', '.join(STORAGES)}")
        self.storage = storage
        self.values = np.zeros((n, dim), DTYPES[storage])
        self.scale = np.ones(n, np.float32) if storage == "int8" else None
        self.floats = np.zeros((n, dim), np.float32) if keep_float else None
        self._filled = np.zeros(n, bool)

    def put(self, rows: np.ndarray, x: np.ndarray) -> None:
        """Store float encodings ``x`` (B, D) as references ``rows`` (B,) int."""
        packed = Encodings.pack(x, self.storage)
        self.values[rows] = packed.values
        if self.scale is not None:
            self.scale[rows] = packed.scale
        if self.floats is not None:
            self.floats[rows] = x
        self._filled[rows] = True

    def encodings(self) -> Encodings:
        """The stored encodings; every row must have been put."""
        if not self._filled.all():
            raise ValueError(f"{int((~self._filled).sum())} references were never encoded")
        return Encodings(self.values, self.storage, self.scale)
