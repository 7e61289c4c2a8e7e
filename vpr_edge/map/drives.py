"""A map's drives: its places as one or more sequences, each the frames of one drive (a folder, a video, a bag
or a descriptor file) in the order they were taken, one after another in the map.

A map of one folder is one drive. A map of several keeps each drive's order and its boundaries, so that the
matcher does not take the last place of one drive and the first of the next for neighbours, the output line
says which drive an answer is from, and ``--append`` adds drives rather than more places after the last one.

Where drives meet (``junctions``): with positions, a drive's end continues into the place of another drive
nearest to it, and a drive's start follows the place of another drive nearest to it, when that place lies within
``JOIN_STEPS`` of the map's typical spacing of places and, where both have a heading, points within
``JOIN_HEADING_DEG`` of the same way; without positions, any drive's end may continue into any drive's start
(the evidence of the frames after it decides which, as it decides speeds).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vpr_edge.errors import VprError
from vpr_edge.positions import Positions, distances

JOIN_STEPS = 3.0          # positions: drives meet within this many times the median spacing of places ...
JOIN_MIN_M = 5.0          # ... and at least this many metres (GPS noise)
JOIN_HEADING_DEG = 60.0   # ... pointing the same way within this (where both headings are known)


@dataclass(frozen=True)
class Drive:
    """One drive: its ``name`` (unique in the map), its places ``first`` .. ``first + count - 1``, where its
    frames came from (``source``: the folder or file as given; None if not known) and its time span
    (``span``: first and last frame time in seconds, where known)."""

    name: str
    first: int
    count: int
    source: str | None = None
    span: tuple[float, float] | None = None

    @property
    def last(self) -> int:
        return self.first + self.count - 1

    def meta(self) -> dict:
        out: dict = {"name": self.name, "first": self.first, "count": self.count}
        if self.source is not None:
            out["source"] = self.source
        if self.span is not None:
            out["span"] = [float(self.span[0]), float(self.span[1])]
        return out


@dataclass(frozen=True)
class Drives:
    """A map's drives in map order, covering its places 0..R-1 without gaps (checked)."""

    items: tuple[Drive, ...]

    def __post_init__(self) -> None:
        if not self.items:
            raise ValueError("a map has at least one drive")
        at = 0
        for d in self.items:
            if d.first != at or d.count < 1:
                raise ValueError(f"drive {d.name!r} does not follow the drive before it (places {d.first}.."
                                 f"{d.last}, expected to start at {at})")
            at += d.count
        check_unique([d.name for d in self.items], "the map")

    @classmethod
    def single(cls, name: str, count: int, source: str | None = None) -> "Drives":
        """One drive of ``count`` places (a map of one folder)."""
        return cls((Drive(name, 0, count, source),))

    @classmethod
    def of(cls, names: Sequence[str], counts: Sequence[int], sources: Sequence[str | None] | None = None,
           spans: Sequence[tuple[float, float] | None] | None = None) -> "Drives":
        """Drives of ``counts`` places each, in this order (VprError for two of one name)."""
        firsts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(int)
        sources = sources or [None] * len(names)
        spans = spans or [None] * len(names)
        return cls(tuple(Drive(n, int(f), int(c), s, p) for n, f, c, s, p in
                         zip(names, firsts, counts, sources, spans)))

    def __len__(self) -> int:
        return len(self.items)

    @property
    def n_refs(self) -> int:
        return self.items[-1].first + self.items[-1].count

    @property
    def names(self) -> list[str]:
        return [d.name for d in self.items]

    @property
    def starts(self) -> np.ndarray:
        """(D,) int64: each drive's first place."""
        return np.array([d.first for d in self.items], np.int64)

    @property
    def lasts(self) -> np.ndarray:
        """(D,) int64: each drive's last place."""
        return np.array([d.last for d in self.items], np.int64)

    def of_each(self) -> np.ndarray:
        """(R,) int64: each place's drive (its index)."""
        return np.repeat(np.arange(len(self.items)), [d.count for d in self.items])

    def index(self, ref: int) -> int:
        """The drive (its index) that place ``ref`` belongs to."""
        return int(np.searchsorted(self.starts, ref, side="right")) - 1

    def of_ref(self, ref: int) -> Drive:
        return self.items[self.index(ref)]

    def then(self, more: "Drives") -> "Drives":
        """These drives, then ``more``'s after them (an append); VprError naming a drive name given twice."""
        check_unique(self.names + more.names, "the map and the appended drives")
        shift = self.n_refs
        return Drives(self.items + tuple(Drive(d.name, d.first + shift, d.count, d.source, d.span)
                                         for d in more.items))

    def meta(self) -> list[dict]:
        return [d.meta() for d in self.items]

    @classmethod
    def from_meta(cls, value: object, n_refs: int, where: str) -> "Drives":
        """A map's ``drives`` metadata (a list of objects) -> Drives; VprError naming ``where`` if it does not
        describe the map's ``n_refs`` places."""
        try:
            items = []
            for d in value:   # type: ignore[union-attr]
                span = d.get("span")
                if span is not None and (len(span) != 2 or not all(isinstance(t, (int, float)) for t in span)):
                    raise ValueError(f"drive {d.get('name')!r} has a span that is not two times")
                if not isinstance(d["name"], str) or not all(isinstance(d[k], int) for k in ("first", "count")):
                    raise ValueError("a drive needs a name (text), first and count (integers)")
                items.append(Drive(d["name"], d["first"], d["count"], d.get("source"),
                                   None if span is None else (float(span[0]), float(span[1]))))
            drives = cls(tuple(items))
        except (VprError, TypeError, KeyError, ValueError, AttributeError) as e:
            raise VprError(f"{where}: map's drives are inconsistent ({e})") from None
        if drives.n_refs != n_refs:
            raise VprError(f"{where}: map's drives cover {drives.n_refs} places, the map has {n_refs}")
        return drives

    def labels(self, names: Sequence[str]) -> dict[str, int]:
        """Each place's label -> its index: ``DRIVE/NAME`` (the first place of that name in the drive), and in
        a map of one drive also its plain ``NAME`` (how ground truth may name references)."""
        out: dict[str, int] = {}
        for d in self.items:
            for i in range(d.last, d.first - 1, -1):
                out[f"{d.name}/{names[i]}"] = i
                if len(self) == 1:
                    out[names[i]] = i
        return out

    def junctions(self, positions: Positions | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
        """Where drives meet, as (sources, targets) pairs of place arrays: each target place may follow any
        source place (module docstring). Empty for a map of one drive."""
        if len(self) < 2:
            return []
        if positions is None:
            return [(self.lasts, self.starts)]
        out: list[tuple[np.ndarray, np.ndarray]] = []
        radius = join_radius(positions, self)
        for k, d in enumerate(self.items):
            others = np.concatenate([np.arange(o.first, o.last + 1) for j, o in enumerate(self.items) if j != k])
            end = _meeting(positions, d.last, others, radius)      # d's end continues into the place after it
            if end is not None and end + 1 <= self.of_ref(end).last:
                out.append((np.array([d.last]), np.array([end + 1])))
            start = _meeting(positions, d.first, others, radius)   # d's start follows the place before it
            if start is not None and start - 1 >= self.of_ref(start).first:
                out.append((np.array([start - 1]), np.array([d.first])))
        return out


def check_unique(names: Sequence[str], where: str) -> None:
    """VprError naming a drive name that ``names`` hold twice (``where``: whose names they are)."""
    seen: set[str] = set()
    for n in names:
        if n in seen:
            raise VprError(f"two drives named {n!r} in {where}: name them apart (NAME=PATH)")
        seen.add(n)


def join_radius(positions: Positions, drives: Drives) -> float:
    """Metres within which two drives meet: ``JOIN_STEPS`` x the median spacing of consecutive places within
    drives, at least ``JOIN_MIN_M``."""
    steps = np.concatenate([positions.steps()[d.first:d.last] for d in drives.items if d.count > 1] or [[0.0]])
    return max(JOIN_MIN_M, JOIN_STEPS * float(np.median(steps)))


def _meeting(positions: Positions, ref: int, others: np.ndarray, radius: float) -> int | None:
    """The place among ``others`` nearest to place ``ref`` within ``radius`` metres and, where both headings are
    known, pointing the same way within ``JOIN_HEADING_DEG``; None if there is none."""
    d = distances(positions.coords[ref:ref + 1], positions.coords[others], positions.geo)[0]
    a, b = positions.heading[ref], positions.heading[others]
    turn = np.abs((b - a + 180.0) % 360.0 - 180.0)
    ok = (d <= radius) & ~(np.isfinite(turn) & (turn > JOIN_HEADING_DEG))
    if not ok.any():
        return None
    return int(others[np.flatnonzero(ok)[np.argmin(d[ok])]])


def spans_of(stamps: Sequence[float] | None) -> tuple[float, float] | None:
    """(first, last) of a drive's frame times in seconds, or None where they are not known."""
    if stamps is None or len(stamps) == 0:
        return None
    values = np.asarray(stamps, np.float64)
    values = values[np.isfinite(values)]
    return None if not len(values) else (float(values.min()), float(values.max()))


def drive_name(path: str, given: str | None = None) -> str:
    """A drive's name: ``given``, else its folder's or file's name without the suffix."""
    if given is not None:
        return given
    p = Path(path)
    return p.name if p.is_dir() else p.stem or p.name


__all__ = ["Drive", "Drives", "JOIN_HEADING_DEG", "JOIN_MIN_M", "JOIN_STEPS", "check_unique", "drive_name",
           "join_radius", "spans_of"]
