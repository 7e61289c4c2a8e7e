"""Where the reference places are: a route's positions (``model``: ``Positions``, in metres or degrees),
distances between them (``distance``), and their sources, one module each, read through one call
(``source.read_positions``): a CSV file (``csv``), the images' EXIF GPS tags (``exif``), a GPX track
(``gpx``) and a bag's NavSatFix / Odometry topic (``bag``), with the references between fixes filled in
(``fill``)."""
from vpr_edge.positions.distance import EARTH_RADIUS_M, distances, paired_distances
from vpr_edge.positions.model import FRAMES, Positions, check_range
from vpr_edge.positions.source import PositionSource, read_positions

__all__ = ["EARTH_RADIUS_M", "FRAMES", "PositionSource", "Positions", "check_range", "distances",
           "paired_distances", "read_positions"]
