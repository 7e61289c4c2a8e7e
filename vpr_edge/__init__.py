"""vpr-edge: visual place recognition by sequence matching of encoded deep features, on ONNX Runtime.

``from vpr_edge import Localizer`` (see ``vpr_edge.api``); imported lazily so that ``vpr_edge.__version__``
costs nothing.
"""
__version__ = "0.1.0"
__all__ = ["Localizer", "Match", "__version__"]


def __getattr__(name: str):
    if name in ("Localizer", "Match"):
        from vpr_edge import api

        return getattr(api, name)
    raise AttributeError(f"module 'vpr_edge' has no attribute {name!r}")
