"""Front ends: RGB images -> local descriptors (B, N, K), one contract (``base``), one module each, one
registry (``registry``). ``cnn`` is an ONNX layer tap; the others are handcrafted and need no model."""
from vpr_edge.features.base import FrontEnd, Handcrafted, grey, spec_fingerprint
from vpr_edge.features.registry import FRONT_ENDS, make_front_end

__all__ = ["FRONT_ENDS", "FrontEnd", "Handcrafted", "grey", "make_front_end", "spec_fingerprint"]
