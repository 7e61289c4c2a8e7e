"""Reading rows of a memory-mapped map without keeping its pages: ``release_pages`` after a whole pass,
``RowReader`` (``pread`` into a bounded cache) for scattered rows."""
from __future__ import annotations

import mmap as mmap_module
import os
import threading
import weakref

import numpy as np


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
    the pages they touch mapped, and a kernel may map page-cache pages in large folios, so a few thousand rows read at
    random can map half a large map (docs/decisions.md, "Tried and not taken"). Read this way, the process holds the
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
