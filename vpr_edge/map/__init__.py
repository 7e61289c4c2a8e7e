"""The map, by job. Its data and file: ``model`` (``PlaceMap``), ``io`` (the ``.npz`` format, schema
versions), ``drives`` (its drives and where they meet), ``summary`` (what ``vpr-edge info`` shows). Building
it: ``options`` (``BuildOptions``), ``plan`` (``plan_map``: every check and default, no work), ``make``
(``gather`` the drives, then ``write_map``), ``build`` (describe, fit, encode) and ``fleet`` (that work on a
Ray cluster). Querying it: ``front`` (the front end its queries need) and ``query`` (``MapQuery``: the chain
every query frame takes)."""
from vpr_edge.map.build import build_map, map_from_local
from vpr_edge.map.front import map_front_end
from vpr_edge.map.io import MAP_SCHEMA, load_map, save_map
from vpr_edge.map.model import PlaceMap, Svm
from vpr_edge.map.query import MapQuery

__all__ = ["MAP_SCHEMA", "MapQuery", "PlaceMap", "Svm", "build_map", "load_map", "map_from_local", "map_front_end", "save_map"]
