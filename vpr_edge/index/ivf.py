"""An inverted-file index over a map's own stored rows: a frame's candidate places among a million in a few
milliseconds, with no second copy of the vectors.

Built with the map (``build-map``, maps of ``IVF_MIN_REFS`` places or more, or ``--index ivf``): spherical
k-means ``centroids`` (C, D) fitted on a sample of the references (``KMEANS_ITERATIONS`` Lloyd steps, each one
matrix product: scikit-learn's ``KMeans`` was far slower on the same sample, and a million places must build
in two minutes; docs/design.md), every reference assigned to its most similar centroid, the references listed
by centroid (``order``
(R,) int32, list c being ``order[offsets[c]:offsets[c + 1]]``). A frame's candidates (``candidates``): the
``nprobe`` lists whose centroids are most similar to it, their members scored exactly against the map's
stored rows (a memory-mapped map reads only those rows), the best ``k``. The index is C x D float32 and 4
bytes a place (8 MB + 4 MB at a million 512-dim places), stored in the map file.
"""
from __future__ import annotations

from collections import deque

import numpy as np

from vpr_edge.errors import VprError
from vpr_edge.index.encodings import Encodings

IVF_MIN_REFS = 50_000     # build-map indexes maps at least this long (shorter ones: a whole-route pass is cheap)
SAMPLE_PER_LIST = 32      # references sampled per list to fit the centroids ...
MAX_SAMPLE = 65_536       # ... at most
KMEANS_ITERATIONS = 8
NPROBE = 16               # lists searched per frame
CANDIDATES = 64           # candidates a frame gives the matcher


def lists_for(n_refs: int) -> int:
    """Lists of a route of ``n_refs`` places: about 2 sqrt(n_refs) (2,000 at a million), at least 1."""
    return max(1, int(round(2 * np.sqrt(n_refs))))


class IvfIndex:
    """``centroids`` (C, D) float32 unit rows, ``order`` (R,) int32, ``offsets`` (C + 1,) int64 (module
    docstring)."""

    def __init__(self, centroids: np.ndarray, order: np.ndarray, offsets: np.ndarray) -> None:
        c = len(centroids)
        if np.ndim(centroids) != 2 or np.shape(offsets) != (c + 1,) or np.ndim(order) != 1 or \
                int(offsets[0]) != 0 or int(offsets[-1]) != len(order) or (np.diff(offsets) < 0).any():
            raise ValueError("index lists do not fit their centroids")
        self.centroids, self.order, self.offsets = centroids, order, offsets

    def __len__(self) -> int:
        return len(self.order)

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {"index_centroids": self.centroids, "index_order": self.order, "index_offsets": self.offsets}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], n_refs: int, dim: int) -> "IvfIndex":
        """The index a map stores; ValueError if it does not fit the map's ``n_refs`` places of ``dim`` dims."""
        centroids = np.asarray(arrays["index_centroids"], np.float32)
        order, offsets = arrays["index_order"], np.asarray(arrays["index_offsets"], np.int64)
        if centroids.shape[1:] != (dim,) or len(order) != n_refs or not np.isfinite(centroids).all() or \
                order.dtype.kind not in "iu" or (n_refs and (int(order.min()) < 0 or int(order.max()) >= n_refs)):
            raise ValueError(f"index does not fit the {n_refs} places of {dim} dims")
        return cls(centroids, order, offsets)

    def lists(self, q: np.ndarray, nprobe: int = NPROBE) -> np.ndarray:
        """The ``nprobe`` lists (C indices) whose centroids are most similar to query ``q`` (D,)."""
        sims = self.centroids @ np.asarray(q, np.float32)
        n = min(nprobe, len(sims))
        return np.argpartition(-sims, n - 1)[:n]

    def members(self, lists: np.ndarray) -> np.ndarray:
        """The places of ``lists`` (sorted int64)."""
        parts = [self.order[self.offsets[c]:self.offsets[c + 1]] for c in lists]
        return np.sort(np.concatenate(parts).astype(np.int64)) if parts else np.zeros(0, np.int64)

    def candidates(self, stored: Encodings, q: np.ndarray, k: int = CANDIDATES, nprobe: int = NPROBE) -> np.ndarray:
        """The ``k`` places most similar to query ``q`` (D,) among the members of its ``nprobe`` nearest
        lists, scored exactly against ``stored`` (best first; fewer if the lists hold fewer)."""
        rows = self.members(self.lists(q, nprobe))
        if not len(rows):
            return rows
        sims = stored.similarity(np.asarray(q, np.float32)[None], rows)[0]
        n = min(k, len(rows))
        top = np.argpartition(-sims, n - 1)[:n]
        return rows[top[np.argsort(-sims[top], kind="stable")]]


class SequenceQuery:
    """What a stream asks the index: the mean of its last ``frames`` encodings (a sequence descriptor). A
    frame's own encoding may be far from its place's among a million; consecutive frames show alike places
    with independent noise, so their mean is nearer (what it buys: docs/results.md, "A million
    places")."""

    def __init__(self, frames: int) -> None:
        self.frames = max(1, int(frames))
        self._recent: deque[np.ndarray] = deque(maxlen=self.frames)

    def push(self, encoding: np.ndarray) -> None:
        """Add a frame's encoding (D,)."""
        self._recent.append(np.asarray(encoding, np.float32))

    def query(self) -> np.ndarray:
        """The mean of the recent encodings (D,) float32 (the last frame's alone when ``frames`` is 1)."""
        return self._recent[-1] if len(self._recent) == 1 else np.mean(self._recent, axis=0, dtype=np.float32)

    def reset(self) -> None:
        self._recent.clear()


def fit_ivf(stored: Encodings, lists: int | None = None, seed: int = 0, block: int = 8192) -> IvfIndex:
    """The index of ``stored`` (R, D): ``lists`` centroids (default ``lists_for(R)``) fitted by k-means on a
    sample of ``SAMPLE_PER_LIST`` rows a list (at most ``MAX_SAMPLE``), then every row assigned, ``block`` rows
    at a time (memory: the sample and one block as float32)."""
    r = stored.shape[0]
    c = min(r, lists or lists_for(r))
    rng = np.random.default_rng(seed)
    sample_rows = np.sort(rng.choice(r, min(r, MAX_SAMPLE, SAMPLE_PER_LIST * c), replace=False))
    sample = _unit(stored.take(sample_rows).astype(np.float32))   # a row's positive scale: no matter
    centroids = spherical_kmeans(sample, c, rng)
    assign = np.empty(r, np.int32)
    for i, values in stored.blocks(block):   # the most similar centroid: a row's positive scale does not change it
        assign[i:i + len(values)] = np.argmax(centroids @ values.astype(np.float32).T, axis=0)
    order = np.argsort(assign, kind="stable").astype(np.int32)
    offsets = np.concatenate([[0], np.cumsum(np.bincount(assign, minlength=c))]).astype(np.int64)
    return IvfIndex(centroids, order, offsets)


def spherical_kmeans(x: np.ndarray, c: int, rng: np.random.Generator,
                     iterations: int = KMEANS_ITERATIONS) -> np.ndarray:
    """Unit rows ``x`` (n, D) -> ``c`` unit centroids (c, D) float32: started at ``c`` random rows, then
    ``iterations`` Lloyd steps by cosine (each row to its most similar centroid, each centroid the normalised
    sum of its rows; one left empty keeps its place)."""
    centroids = x[rng.choice(len(x), c, replace=False)].copy()
    for _ in range(iterations):
        assign = np.argmax(x @ centroids.T, axis=1)
        order = np.argsort(assign, kind="stable")
        used, starts = np.unique(assign[order], return_index=True)
        centroids[used] = _unit(np.add.reduceat(x[order], starts, axis=0))
    return centroids


def _unit(x: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(x, axis=1, keepdims=True)
    if not np.isfinite(x).all():
        raise VprError("cannot index non-finite encodings")
    return (x / np.maximum(n, 1e-12)).astype(np.float32)
