"""The map: what it holds (``model``), its file (``io``), the front end its queries go through (``front``),
building it from images (``build``), the build-map command as one library function (``make``) and a map opened
for queries (``query``: the chain every query frame takes)."""
from vpr_edge.map.build import build_map, map_from_local
from vpr_edge.map.front import map_front_end
from vpr_edge.map.io import MAP_SCHEMA, load_map, save_map
from vpr_edge.map.model import PlaceMap, Svm
from vpr_edge.map.query import MapQuery

__all__ = ["MAP_SCHEMA", "MapQuery", "PlaceMap", "Svm", "build_map", "load_map", "map_from_local", "map_front_end", "save_map"]
