"""The front end a map's queries must go through: rebuilt from the map's record, its model found and checked."""
from __future__ import annotations

import os
from pathlib import Path

from vpr_edge.errors import InputError, VprError
from vpr_edge.features import FrontEnd, make_front_end
from vpr_edge.features.choice import DEFAULT_PRECISION, bundled_for_sha256, choose_form, int8_sibling
from vpr_edge.features.cnn import resolve_model
from vpr_edge.files.readers import file_sha256
from vpr_edge.map.model import PlaceMap


def front_end_meta(front: FrontEnd) -> dict:
    """What a map records of its front end: its description, fingerprint and identity (the model for cnn)."""
    return {"features": front.describe(), "features_fingerprint": front.fingerprint} | front.identity()


def map_model_path(place_map: PlaceMap, given: Path | None) -> Path:
    """The model to localise with: ``given``, else ``$VPR_EDGE_MODEL``, else the file the map was built
    with if it is still there, else the bundled model with that file's SHA-256 (a map made on another
    install), else the bundled default (``features.cnn.resolve_model``)."""
    recorded = Path(place_map.meta.get("model_path") or "")
    if given is None and not (recorded.name and recorded.is_file()):
        recorded = bundled_for_sha256(place_map.meta.get("model_sha256")) or recorded
    return resolve_model(given, recorded)


def map_front_end(place_map: PlaceMap, map_path: str | os.PathLike[str], model: Path | None = None,
                  threads: int = 0, precision: str = DEFAULT_PRECISION) -> FrontEnd:
    """The front end this map's queries must go through (its model for cnn, checked: VprError naming
    ``map_path`` if it is another model; ``model`` given to a handcrafted map is an error too). For cnn,
    ``precision`` picks the model's form (``features.choice.choose_form``: auto runs the int8 form kept
    beside the model where the CPU has int8 dot products); the front end's ``form`` says which and why.
    VprError too when the front end the map names gives descriptors its codebook does not take (metadata
    that does not fit the map's arrays), before any frame."""
    front = _front_end(place_map, map_path, model, threads, precision)
    takes = getattr(place_map.encoder, "input_dim", None)
    if isinstance(takes, int) and takes > 0 and front.dim != takes:
        raise VprError(f"{map_path}: map is inconsistent (its metadata names the {front.name} front end, "
                       f"{front.dim}-dim descriptors, but its codebook takes {takes}-dim ones); rebuild it")
    return front


def _front_end(place_map: PlaceMap, map_path: str | os.PathLike[str], model: Path | None, threads: int,
               precision: str) -> FrontEnd:
    name = place_map.features["name"]
    if name != "cnn":
        if model is not None:
            raise InputError("{map}: map was built with the {name} front end, which takes no model; drop {opt.model}",
                             map=map_path, name=name)
        return make_front_end(name, spec=place_map.features)
    path, recorded = map_model_path(place_map, model), place_map.meta.get("model_sha256")
    # an int8 form to run instead: only its session is opened (the fp32 file is checked by its hash)
    if (precision != "fp32" and path.is_file() and int8_sibling(path) is not None
            and file_sha256(path) == recorded):
        chosen, why = choose_form(path, precision)
        if chosen != path:
            fast = make_front_end("cnn", chosen, threads, spec=place_map.features)
            if fast.source_fingerprint == recorded:
                return fast.as_run(why)
            if precision == "int8":
                raise InputError("{chosen}: not quantised from {name} (its metadata names another source); "
                                 "{opt.precision} int8 cannot be met", chosen=chosen, name=path.name)
            why = f"fp32: {chosen.name} was quantised from another model"
        return make_front_end("cnn", path, threads, spec=place_map.features).as_run(why)
    front = make_front_end("cnn", path, threads, spec=place_map.features)
    if front.fingerprint == recorded and front.source_fingerprint is None:
        return front.as_run(choose_form(path, precision)[1])    # fp32 (VprError: int8 asked, no int8 form)
    if front.source_fingerprint is not None and front.source_fingerprint == recorded:
        return front.as_run("int8: given")      # an int8 form of the map's model, given as the model
    if front.fingerprint != recorded:
        m, given = place_map.meta.get("model", {}), front.identity()
        info = given.get("model", {})
        raise InputError(
            "{map}: map was built with model {built} ({file}, sha256 {sha}) but {given} is {other} (sha256 "
            "{given_sha}); pass {opt.model} with the map's model", map=map_path,
            built=f"{m.get('backbone')}/{m.get('tap')}", file=place_map.meta.get("model_file"),
            sha=str(place_map.meta.get("model_sha256"))[:12], given=given.get("model_path", "?"),
            other=f"{info.get('backbone')}/{info.get('tap')}", given_sha=front.fingerprint[:12])
    return front
