"""Ground truth for evaluation, from three sources, as a padded int array (Q, T): per query its correct
references, -1 as padding (a row of -1: the query's place is not in the map).

* the project's CSV: header ``query,references``, one row per query 0..Q-1, space-separated references
  (indices, or with a map ``DRIVE/NAME`` labels: a drive and an image name in it), an empty field for a
  place that is not in the map;
* a boolean (Q, R) ``.npy`` matrix, True where query and reference show the same place (VPR_Tutorial's
  GThard / GTsoft), read without pickle;
* positions: two CSV files (references, queries) with columns ``x,y`` (metres) or ``lat,lon`` (degrees);
  the correct references of a query are those within a radius in metres.

``write_ground_truth`` writes the project's CSV (what a user's own labelled drive, or a test, gives ``evaluate``).
"""
from __future__ import annotations

import csv
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vpr_edge.errors import InputError, VprError
from vpr_edge.files.atomic import atomic_output
from vpr_edge.files.readers import read_csv_rows
from vpr_edge.positions import Positions, distances
from vpr_edge.positions.csv import read_csv


def pad(sets: Sequence[Sequence[int]]) -> np.ndarray:
    """Lists of reference indices -> (Q, T) int64 padded with -1 (T >= 1)."""
    width = max([len(s) for s in sets] + [1])
    out = np.full((len(sets), width), -1, np.int64)
    for q, s in enumerate(sets):
        out[q, : len(s)] = s
    return out


def load_csv(path: str | os.PathLike[str], labels: Callable[[], dict[str, int]] | None = None) -> np.ndarray:
    """The project's ground-truth CSV -> (Q, T) padded truth; references given as labels (``DRIVE/NAME``)
    are looked up in ``labels()`` (a map's ``PlaceMap.labels``; None: indices only)."""
    rows = read_csv_rows(path, "ground truth")
    resolve = _resolver(labels, path)
    rows = [(n, row) for n, row in rows if any(c.strip() for c in row)]   # a spreadsheet's empty rows
    if not rows or [c.strip().lower() for c in rows[0][1][:2]] != ["query", "references"]:
        raise VprError(f"{path}: not a ground-truth CSV (expected the header 'query,references')")
    out: dict[int, list[int]] = {}
    line_of: dict[int, int] = {}
    for n, row in rows[1:]:
        try:
            q = int(row[0])
            tokens = row[1].split() if len(row) > 1 else []
            refs = [int(v) if v.lstrip("-").isdigit() else resolve(v, n) for v in tokens]
        except ValueError:
            raise VprError(f"{path}: line {n}: expected 'query,ref ref ...'") from None
        if q in out:
            raise VprError(f"{path}: line {n}: query {q} has a row already (line {line_of[q]})"
                           + ("" if sorted(out[q]) == sorted(refs) else ", with other references"))
        out[q], line_of[q] = refs, n
    if sorted(out) != list(range(len(out))) or not out:
        raise VprError(f"{path}: query indices must run 0..Q-1 without gaps")
    if any(v < 0 for refs in out.values() for v in refs):
        raise VprError(f"{path}: reference indices must be >= 0")
    return pad([out[i] for i in range(len(out))])


def write_ground_truth(path: str | os.PathLike[str], truth: Sequence[Sequence[int]]) -> None:
    """Write the project's ground-truth CSV (``query,references``; per query its reference indices, space
    separated; empty = place not in the map) atomically: what ``load_csv`` reads."""
    with atomic_output(path) as tmp, open(tmp, "w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(["query", "references"])
        for q, refs in enumerate(truth):
            w.writerow([q, " ".join(str(int(r)) for r in refs)])


def _resolver(labels: Callable[[], dict[str, int]] | None, path: str | os.PathLike[str]
              ) -> Callable[[str, int], int]:
    """A reference named ``DRIVE/NAME`` on line ``line`` -> its index, the map's labels read once on first use
    (VprError naming the file and line if there is none)."""
    table: dict[str, int] = {}

    def resolve(token: str, line: int) -> int:
        if labels is None:
            raise InputError("{path}: line {line}: reference {token!r} is a name; names are read against a map "
                             "({opt.map})", path=path, line=line, token=token)
        if not table:
            table.update(labels())
        if token not in table:
            raise VprError(f"{path}: line {line}: no reference {token!r} in the map (references are DRIVE/NAME)")
        return table[token]
    return resolve


def load_matrix(path: str | os.PathLike[str]) -> np.ndarray:
    """A (Q, R) boolean ``.npy`` matrix -> (Q, T) padded truth."""
    try:
        m = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as e:
        raise VprError(f"{path}: not a readable .npy ground-truth matrix ({str(e).splitlines()[0][:100]})") from None
    if m.ndim != 2 or not (m.dtype == bool or np.issubdtype(m.dtype, np.integer)):
        raise VprError(f"{path}: ground-truth matrix must be 2-D boolean (queries x references), "
                       f"got {m.ndim}-D {m.dtype}")
    m = m.astype(bool)
    q, r = np.nonzero(m)
    return pad(np.split(r, np.cumsum(m.sum(axis=1))[:-1]))


def from_positions(refs_csv: str | os.PathLike[str], queries_csv: str | os.PathLike[str],
                   radius_m: float, chunk: int = 512) -> np.ndarray:
    """References within ``radius_m`` metres of each query -> (Q, T) padded truth."""
    refs, queries = read_csv(refs_csv), read_csv(queries_csv)
    refs.check_frame(queries, str(queries_csv), f"{refs_csv}'s (the same columns needed)")
    return within(queries, refs, radius_m, chunk)


def within(queries: Positions, refs: Positions, radius_m: float, chunk: int = 512) -> np.ndarray:
    """References within ``radius_m`` metres of each query position -> (Q, T) padded truth."""
    qp, rp = queries.coords, refs.coords
    sets: list[np.ndarray] = []
    for i in range(0, len(qp), chunk):
        near = distances(qp[i:i + chunk], rp, refs.geo) <= radius_m
        sets.extend(np.flatnonzero(row) for row in near)
    return pad(sets)


def one_view(truth: np.ndarray, same_view: np.ndarray) -> np.ndarray:
    """Frames whose place no image can pin to a reference: ``truth`` (Q, T) padded, ``same_view`` (R,) bool,
    True where a reference shows the view of the one before it (the map's drive stood still, or saw nothing:
    ``motion.route_stands`` of the map) -> (Q,) bool, True where a truth reference lies in a run of such
    references or is the reference that run repeats. Within a run every reference shows one view, so an answer
    anywhere in it looks as right as the truth's, and a truth of +-k frames there is a count, not a view."""
    same_view = np.asarray(same_view, bool)
    run = same_view.copy()
    run[:-1] |= same_view[1:]          # the reference a run repeats
    hit = np.zeros(truth.shape, bool)
    ok = truth >= 0
    hit[ok] = run[truth[ok]]
    return hit.any(axis=1)


@dataclass(frozen=True)
class Truth:
    """Where an evaluation's ground truth comes from, read by this module's loaders (``load``): ``gt`` (the
    project's CSV, or a boolean (Q, R) .npy matrix) or ``positions`` (reference and query CSVs of x,y or
    lat,lon; references within ``radius`` metres are correct)."""

    gt: str | os.PathLike[str] | None = None
    positions: tuple[str | os.PathLike[str], str | os.PathLike[str]] | None = None
    radius: float = 25.0

    def load(self, map_positions: Positions | None = None, labels: Callable[[], dict[str, int]] | None = None
             ) -> tuple[np.ndarray, tuple[int, ...] | None]:
        """(Q, T) padded correct references, and the (Q, R) shape of a matrix file (else None). With
        ``positions`` ("map", QUERIES.csv) the references' positions are ``map_positions`` (the map's own);
        a CSV's references named ``DRIVE/NAME`` are looked up in ``labels()`` (the map's)."""
        if (self.gt is None) == (self.positions is None):
            raise InputError("give ground truth: {opt.gt} FILE (.csv or .npy) or {opt.gt_positions} REFS.csv QUERIES.csv")
        if self.positions is not None and str(self.positions[0]) == "map":
            if map_positions is None:
                raise InputError("{opt.gt_positions} map ...: the references' positions come from {opt.map}, which "
                                 "must be built with {opt.positions}")
            queries = read_csv(self.positions[1])
            map_positions.check_frame(queries, str(self.positions[1]), "the map's frame's")
            return within(queries, map_positions, self.radius), None
        if self.positions is not None:
            return from_positions(self.positions[0], self.positions[1], self.radius), None
        if Path(self.gt).suffix.lower() == ".npy":
            return load_matrix(self.gt), np.load(self.gt, mmap_mode="r").shape
        return load_csv(self.gt, labels), None

    @property
    def name(self) -> str:
        return str(self.gt if self.gt is not None else self.positions[0])
