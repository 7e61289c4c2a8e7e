"""Positions from a CSV file: a header naming x,y (metres) or lat,lon (degrees), rows matched to the
references by name or in order."""
from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vpr_edge.errors import VprError
from vpr_edge.files.readers import read_csv_rows
from vpr_edge.positions.fill import by_order
from vpr_edge.positions.model import FRAMES, Positions, check_range

NAME_COLUMNS = ("name", "frame", "file", "image")
ALTITUDE_COLUMNS = ("z", "alt", "altitude")


def _number(text: str, path: Path, line: int, column: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise VprError(f"{path}: line {line}: {column} {text!r} is not a number") from None
    if not np.isfinite(value):
        raise VprError(f"{path}: line {line}: {column} is not finite")
    return value


def read_csv(path: str | os.PathLike[str], names: Sequence[str] | None = None) -> Positions:
    """Positions from a CSV file with a header: ``x,y`` (metres) or ``lat,lon`` (degrees), optionally ``z`` /
    ``alt`` and ``heading``, and optionally a ``name`` (or ``frame``, ``file``, ``image``) column naming each
    row's reference image. Given ``names`` (the references, in map order), rows are matched by name, or in
    order when there is no name column (then there must be one row per reference). A row with empty
    coordinates, or a reference no row names, has no fix: it is interpolated along the route's order between
    the fixes either side (with a warning); one before the first fix or after the last is an error."""
    path = Path(path)
    rows = read_csv_rows(path, "positions")
    head = [c.strip().lower() for c in rows[0][1]] if rows else []
    found = [frame for frame, cols in FRAMES.items() if all(c in head for c in cols)]
    if len(found) != 1:
        raise VprError(f"{path}: positions need columns x,y (metres) or lat,lon (degrees) in the header"
                       + (", not both (positions in two frames)" if len(found) > 1 else ""))
    frame = found[0]
    ix = [head.index(c) for c in FRAMES[frame]]
    extra = {"heading": next((head.index(c) for c in ("heading", "yaw") if c in head), None),
             "altitude": next((head.index(c) for c in ALTITUDE_COLUMNS if c in head), None)}
    name_col = next((head.index(c) for c in NAME_COLUMNS if c in head), None)
    body = rows[1:]   # "," is a row without a fix
    if not body:
        raise VprError(f"{path}: no positions")
    count = len(names) if names is not None else len(body)
    if names is not None and name_col is None and len(body) != count:
        raise VprError(f"{path}: {len(body)} positions but {count} references (give one row per reference, in "
                       f"order, or a name column)")
    coords = np.full((count, 2), np.nan)
    heading, altitude = np.full(count, np.nan), np.full(count, np.nan)
    where = {name: i for i, name in enumerate(names)} if names is not None and name_col is not None else None
    for k, (line, row) in enumerate(body):
        cells = row + [""] * (len(head) - len(row))
        if where is not None:
            name = cells[name_col].strip()
            if name not in where:
                raise VprError(f"{path}: line {line}: {name!r} is not one of the references")
            i = where[name]
        else:
            i = k
        text = [cells[j].strip() for j in ix]
        if all(text):
            coords[i] = [_number(t, path, line, c) for t, c in zip(text, FRAMES[frame])]
        elif any(text):
            raise VprError(f"{path}: line {line}: give both {' and '.join(FRAMES[frame])}, or neither (no fix)")
        for key, j in extra.items():
            if j is not None and cells[j].strip():
                (heading if key == "heading" else altitude)[i] = _number(cells[j].strip(), path, line, key)
    try:
        check_range(coords[np.isfinite(coords).all(axis=1)], frame, str(path))
    except ValueError as e:
        raise VprError(str(e)) from None
    return by_order(coords, frame, heading % 360.0, altitude, str(path))
