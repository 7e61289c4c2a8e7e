"""Where a drive's positions come from (``PositionSource``: a CSV file, the images' EXIF tags, a GPX track or
a bag's topic), named before any is read, and the one call that reads any of them (``read_positions``)."""
from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vpr_edge.errors import VprError
from vpr_edge.positions.bag import bag_positions
from vpr_edge.positions.csv import read_csv
from vpr_edge.positions.exif import from_exif, require_exifread
from vpr_edge.positions.gpx import from_gpx, require_gpxpy
from vpr_edge.positions.model import Positions

KINDS = ("csv", "exif", "gpx", "bag")


@dataclass(frozen=True)
class PositionSource:
    """A drive's positions, not yet read: ``kind`` csv (rows by reference name, or one per reference in
    order), exif (the images' GPS tags), gpx (a track matched to the frames by time) or bag (a NavSatFix /
    Odometry ``topic`` of the bag at ``path``, matched by time); ``path`` the file as given (None for exif)."""

    kind: str
    path: str | None = None
    topic: str | None = None

    @classmethod
    def given(cls, text: str | os.PathLike[str]) -> "PositionSource":
        """The source a user names: ``exif``, a GPX track (``.gpx``), else a CSV file."""
        text = os.fspath(text)
        if text == "exif":
            return cls("exif")
        return cls("gpx" if text.lower().endswith(".gpx") else "csv", text)

    @classmethod
    def of_bag(cls, path: str | os.PathLike[str], topic: str) -> "PositionSource":
        return cls("bag", os.fspath(path), topic)

    @property
    def by_time(self) -> bool:
        """Matched to the frames by their times (which must then be known), not by name or order."""
        return self.kind in ("gpx", "bag")

    def require(self) -> None:
        """VprError unless the library that reads this kind is installed (checked before any work; a bag's
        rosbags where the bag is opened)."""
        if self.kind == "exif":
            require_exifread()
        elif self.kind == "gpx":
            require_gpxpy(self.path)

    def __str__(self) -> str:
        return "exif" if self.path is None else self.path


def read_positions(source: PositionSource, names: Sequence[str], files: Sequence[Path] = (),
                   stamps: np.ndarray | None = None) -> Positions:
    """The positions of a drive's references from ``source``: ``names`` the references in map order (a CSV's
    rows are matched to them), ``files`` their images (EXIF tags), ``stamps`` (R,) their times in Unix seconds
    (a track or a bag's topic is interpolated to them). References between fixes are interpolated (with a
    warning); VprError naming the file for one that cannot be placed, or a source that does not read."""
    if source.kind == "csv":
        return read_csv(source.path, names)
    if source.kind == "exif":
        return from_exif(files)
    if stamps is None:
        raise VprError(f"{source}: positions matched by time need the frames' times")
    if source.kind == "gpx":
        return from_gpx(source.path, stamps)
    return bag_positions(source.path, source.topic, stamps)
