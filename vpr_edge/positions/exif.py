"""Positions from the reference images' EXIF GPS tags (``exifread``, the ``geo`` extra)."""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vpr_edge.errors import InputError
from vpr_edge.positions.fill import by_order
from vpr_edge.positions.model import Positions


def require_exifread():
    """The exifread module, or InputError naming the extra that brings it (checked before any work)."""
    try:
        import exifread
    except ImportError:
        raise InputError("{opt.positions} exif needs exifread: pip install 'vpr-edge[geo]'") from None
    return exifread


def from_exif(files: Sequence[Path]) -> Positions:
    """Positions from the reference images' EXIF GPS tags (GPSLatitude/Longitude with their N/S, E/W refs,
    GPSAltitude, GPSImgDirection), read with ``exifread`` (the ``geo`` extra). Images without a fix are
    interpolated between those with one (with a warning)."""
    exifread = require_exifread()
    coords = np.full((len(files), 2), np.nan)
    heading, altitude = np.full(len(files), np.nan), np.full(len(files), np.nan)

    def value(tag) -> float:
        parts = [float(v.num) / float(v.den) if getattr(v, "den", 1) else float("nan") for v in tag.values]
        return parts[0] + parts[1] / 60 + parts[2] / 3600 if len(parts) == 3 else parts[0]

    for i, f in enumerate(files):
        try:
            with open(f, "rb") as fh:
                tags = exifread.process_file(fh, details=False)
        except (OSError, ValueError, KeyError, IndexError, TypeError):
            continue
        lat, lon = tags.get("GPS GPSLatitude"), tags.get("GPS GPSLongitude")
        if lat is None or lon is None:
            continue
        sign_lat = -1.0 if str(tags.get("GPS GPSLatitudeRef", "N")).strip().upper().startswith("S") else 1.0
        sign_lon = -1.0 if str(tags.get("GPS GPSLongitudeRef", "E")).strip().upper().startswith("W") else 1.0
        coords[i] = [sign_lat * value(lat), sign_lon * value(lon)]
        if "GPS GPSAltitude" in tags:
            altitude[i] = value(tags["GPS GPSAltitude"])
        if "GPS GPSImgDirection" in tags:
            heading[i] = value(tags["GPS GPSImgDirection"]) % 360.0
    where = str(Path(files[0]).parent) if files else "references"
    coords[~np.isfinite(coords).all(axis=1)] = np.nan
    return by_order(coords, "wgs84", heading, altitude, f"{where} (EXIF GPS)")
