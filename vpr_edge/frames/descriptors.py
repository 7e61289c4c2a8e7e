"""Moved: global descriptor files as a frame source are ``frames.descriptor_files``. This name stays only
until ``map.query`` and ``map.make`` import from there; then it goes."""
from vpr_edge.frames.descriptor_files import descriptor_dims, is_descriptor_file, read_descriptors  # noqa: F401
