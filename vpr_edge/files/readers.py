"""Small whole-file readers: a CSV file's rows as spreadsheets write them, a file's SHA-256."""
from __future__ import annotations

import hashlib
import os

from vpr_edge.errors import VprError


def read_csv_rows(path: str | os.PathLike[str], what: str) -> list[tuple[int, list[str]]]:
    """Every row of a CSV file (the header first) with its line number, as spreadsheets write them: UTF-8
    with or without a byte-order mark, LF or CRLF line ends, blank lines skipped (a row of empty cells,
    ``,,``, is kept: the reader says what it means). VprError ``path: cannot read WHAT (reason)`` for a
    missing, unreadable or non-text file."""
    import csv

    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            reader = csv.reader(f)
            return [(reader.line_num, row) for row in reader if row]
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        raise VprError(f"{path}: cannot read {what} ({getattr(e, 'strerror', None) or e})") from None


def file_sha256(path: str | os.PathLike[str]) -> str:
    """Hex SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()
