"""A folder of derived streams (what ``derive-streams`` writes; ``streams.derive_streams``), as every experiment
finds, checks and evaluates it: one type, one check, one loop over the stream kinds.

Layout: ``ref/`` (the map's places), per stream kind ``KIND/`` (its frames) and ``KIND.csv`` (its ground
truth), and once built ``map.npz`` (``vpr-edge build-map DIR/ref -o DIR/map.npz``: the default map); with
``--drives`` also ``drives/`` (``streams.cut_into_drives``).
"""
from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from pathlib import Path

from vpr_edge.encoders.standardise import STANDARDISE
from vpr_edge.errors import VprError
from vpr_edge.evaluation import Evaluation, Source, Truth, evaluate
from vpr_edge.matchers import Matcher
from vpr_edge_bench.streams import KINDS

MAKE = ("python -m vpr_edge_bench derive-streams --dataset PAIR --out DIR, then vpr-edge build-map DIR/ref -o "
        "DIR/map.npz")


class StreamsFolder:
    """The derived streams in ``path`` (its name names the dataset in tables), of the stream ``kinds``."""

    def __init__(self, path: str | os.PathLike[str], kinds: Sequence[str] = KINDS) -> None:
        self.path = Path(path)
        self.kinds = tuple(kinds)

    def __repr__(self) -> str:
        return f"StreamsFolder({str(self.path)!r})"

    @property
    def name(self) -> str:
        return self.path.name

    @property
    def ref(self) -> Path:
        """The map's reference frames."""
        return self.path / "ref"

    @property
    def map(self) -> Path:
        """The default map of ``ref`` (built by the user or the experiment)."""
        return self.path / "map.npz"

    def frames(self, kind: str) -> Path:
        """The frames of stream ``kind``."""
        return self.path / kind

    def truth(self, kind: str) -> Path:
        """The ground truth of stream ``kind`` (the project's CSV: one row a frame)."""
        return self.path / f"{kind}.csv"

    def check(self, *, map: bool = True, ref: bool = False) -> StreamsFolder:
        """This folder, or VprError naming what it lacks: every stream kind's frames and truth, and ``map.npz``
        with ``map``, ``ref/`` with ``ref`` (called before any work)."""
        need = ([self.map] if map else []) + ([self.ref] if ref else []) + \
            [p for k in self.kinds for p in (self.frames(k), self.truth(k))]
        missing = next((p for p in need if not p.exists()), None)
        if missing is not None:
            raise VprError(f"{self.path}: not a derived-streams folder{' with its map' if map else ''} (no "
                           f"{missing.name}; make one: {MAKE})")
        return self

    def evaluate(self, matchers: dict[str, Matcher], tolerance: int, *, map: Path | None = None,
                 pixels: bool = False, truth_in: Path | None = None, threads: int = 0,
                 kinds: Sequence[str] | None = None, standardise: bool = STANDARDISE
                 ) -> Iterator[tuple[str, Evaluation]]:
        """``evaluate`` (the function behind ``vpr-edge evaluate``) on each stream, in kind order: (kind, its
        evaluation). Frames through ``map`` (default: the folder's map.npz), or with ``pixels`` SeqSLAM's pixel
        front end against ``ref/``; truth from ``truth_in``/KIND.csv (default: the folder's own); ``kinds``:
        a subset of the folder's; ``standardise``: the map's cosines standardised (``evaluate --standardise``)."""
        for kind in self.kinds if kinds is None else kinds:
            source = Source(pixels=True, refs=self.ref, queries=self.frames(kind)) if pixels else \
                Source(map=self.map if map is None else map, queries=self.frames(kind), threads=threads,
                       standardise=standardise)
            gt = self.truth(kind) if truth_in is None else Path(truth_in) / f"{kind}.csv"
            yield kind, evaluate(source, Truth(gt=gt), matchers, tolerance)


def streams_folders(paths: Sequence[str | os.PathLike[str]], *, map: bool = True, ref: bool = False,
                    kinds: Sequence[str] = KINDS, distinct: bool = False) -> list[StreamsFolder]:
    """The folders ``paths`` (an experiment's ``--streams``), each checked (``StreamsFolder.check``) before any
    work; with ``distinct``, VprError unless their names (the datasets' names in tables and outputs) differ."""
    names = [Path(p).name for p in paths]
    if distinct and len(set(names)) != len(names):
        raise VprError(f"--streams: the folders' names name the datasets and must differ: {', '.join(names)}")
    return [StreamsFolder(p, kinds).check(map=map, ref=ref) for p in paths]
