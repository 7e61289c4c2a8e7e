"""A map described (``vpr-edge info``): its size and settings as JSON-ready data."""
from __future__ import annotations

from pathlib import Path

from vpr_edge.errors import VprError
from vpr_edge.map.front import map_front_end
from vpr_edge.map.io import load_map


def summary(path: Path) -> dict:
    """The map at ``path``: references, first and last names, encoding dims, bytes per place, file size (MB),
    its metadata (names said once), its drives, its route (``Positions.summary``) and, for a cnn map, the
    numeric form ``precision`` auto runs here (or why none can), and for an adapted map the drives it was
    adapted on (``adapted_on``)."""
    pm = load_map(path, mmap=True)
    meta = {k: v for k, v in pm.meta.items() if k not in ("names", "n_refs", "dim")}
    route = {"route": pm.positions.summary()} if pm.positions is not None else {}
    meta["drives"] = pm.drives.meta()
    here = {}
    if pm.features.get("name") == "cnn":
        try:
            front = map_front_end(pm, path, precision="auto")
            here = {"precision_auto_here": {k: v for k, v in front.runs().items() if k != "name"}}
        except VprError as e:
            here = {"precision_auto_here": {"error": str(e)}}
    adapted = pm.meta.get("adapted")
    if adapted is not None:   # what it was adapted on, in a line a drive (encoders.adapt)
        here["adapted_on"] = [f"{d.get('frames')} labelled by {d.get('labels')}: {d.get('pairs')} frames"
                              for d in adapted.get("drives", [])]
    return {"references": len(pm.names), "first": pm.names[0], "last": pm.names[-1],
            "encoding_dims": int(pm.stored.shape[1]), "bytes_per_place": pm.stored.bytes_per_place,
            "size_mb": round(path.stat().st_size / 1e6, 2)} | meta | route | here
