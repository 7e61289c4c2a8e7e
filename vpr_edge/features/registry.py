"""Every front end by name: build-map's ``--features``, the map file and the tests read this table."""
from __future__ import annotations

from pathlib import Path

from vpr_edge.errors import InputError, VprError
from vpr_edge.features.base import FrontEnd
from vpr_edge.features.conventions import GivenConventions


FRONT_ENDS: dict[str, str] = {
    "cnn": "an ONNX model (--model; default the bundled EfficientNet-Lite0 stage5 tap): a layer tap's W x H map "
           "as W*H local K-dim descriptors, or a place recognition network's global descriptor (output "
           "(batch, D)), encoded as it is",
    "hog": "OpenCV HOG on the grey image at 128x64: each 16x16 block (4 cells x 9 bins) a local descriptor; "
           "encoding none gives the whole image's HOG",
    "sift": "OpenCV SIFT on a dense grid (every 16 px, 16 px keypoints) of the grey image at 128x96",
    "sift-kp": "OpenCV SIFT on up to 64 detected keypoints of the grey image at 256x192",
    "ldb": "Local Difference Binary (Yang & Cheng 2012) of the whole grey image at 64x64: grid levels 2-5, "
           "intensity and x/y-gradient comparisons, 256 bits selected on the references",
    "pixels": "SeqSLAM's image: grey 64x32, every 8x8 patch normalised (a 64-dim local descriptor each)",
}
# what a map may record besides the image front ends: global descriptors computed elsewhere (a .npy or hloc
# .h5 file given as REFS; ``features.descriptors``), chosen by the file, never by --features
MAP_FRONT_ENDS = (*FRONT_ENDS, "descriptors")


DEFAULT_FRONT_END = "cnn"   # a CNN tap (the bundled model that suits the camera, features.choice)


def make_front_end(name: str, model: Path | None = None, threads: int = 0, spec: dict | None = None,
                   conventions: GivenConventions | None = None) -> FrontEnd:
    """The front end ``name`` with default parameters, or as ``spec`` (a map's ``describe()``) records it.
    ``model``/``threads`` and the input ``conventions`` stated for a model without vpr_edge metadata
    (``features.conventions``) apply to ``cnn`` only. ValueError for an unknown name."""
    params = dict((spec or {}).get("params") or {})
    if name == "cnn":
        from vpr_edge.features.cnn import FeatureExtractor, resolve_model
        from vpr_edge.features.conventions import InputConventions

        resize = params.pop("resize", None)
        recorded = params.pop("input", None)
        if params:
            raise VprError(f"front end cnn: stored parameters not understood ({', '.join(params)})")
        stated = InputConventions.from_record(recorded, "the map's input conventions") if recorded else conventions
        return FeatureExtractor(resolve_model(model), threads, resize, stated)
    if model is not None:
        raise InputError("{model}: front end {name} takes no model; drop {opt.model}", model=model, name=name)
    try:
        if name == "hog":
            from vpr_edge.features.hog import Hog

            return Hog(**params)
        if name in ("sift", "sift-kp"):
            from vpr_edge.features.sift import DenseSift, KeypointSift

            return DenseSift(**params) if name == "sift" else KeypointSift(**params)
        if name == "ldb":
            from vpr_edge.features.ldb import Ldb

            return Ldb(**params)
        if name == "pixels":
            from vpr_edge.features.patches import Patches

            return Patches(**params)
        if name == "descriptors":
            from vpr_edge.features.descriptors import GivenDescriptors

            return GivenDescriptors(**params)
    except TypeError as e:
        raise VprError(f"front end {name}: stored parameters not understood ({e})") from None
    raise ValueError(f"unknown front end {name!r}; choose from {', '.join(MAP_FRONT_ENDS)}")
