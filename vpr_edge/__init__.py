"""vpr-edge: visual place recognition by sequence matching of encoded deep features, on ONNX Runtime.

``from vpr_edge import Localizer`` (see ``vpr_edge.api``); imported lazily so that ``vpr_edge.__version__``
costs nothing.
"""
import os as _os

__version__ = "0.1.0"

# Third-party noise on stderr: OpenCV's FFmpeg backend logs every damaged packet of a video, OpenCV itself
# every backend it probes; vpr-edge reports what matters in its own one-line messages. Set before OpenCV
# loads; a value the user has set wins.
_os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")    # AV_LOG_QUIET
_os.environ.setdefault("OPENCV_LOG_LEVEL", "ERROR")
__all__ = ["Localizer", "Match", "__version__"]


def __getattr__(name: str):
    if name in ("Localizer", "Match"):
        from vpr_edge import api

        return getattr(api, name)
    raise AttributeError(f"module 'vpr_edge' has no attribute {name!r}")
