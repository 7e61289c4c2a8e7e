"""A planned map built (``write_map``): its drives taken in (``map.gather``), every reference described and
encoded (``map.build``), the map written. The build-map command is ``plan_map`` (``map.plan``) then
``write_map``; the CLI and the tools call these, so each default lives in ``map.plan`` once."""
from __future__ import annotations

import contextlib
from dataclasses import replace
from functools import partial

from vpr_edge.errors import InputError
from vpr_edge.files.one_writer import writer_lock
from vpr_edge.frames.images import GreyFrames, load_image
from vpr_edge.index.ivf import IVF_MIN_REFS, fit_ivf
from vpr_edge.map.build import Progress, build_map, map_from_descriptors
from vpr_edge.map.fleet import encode_on_ray
from vpr_edge.map.gather import MapInputs, gather
from vpr_edge.map.io import load_map, save_map
from vpr_edge.map.model import PlaceMap
from vpr_edge.map.options import BuildOptions
from vpr_edge.map.plan import MapPlan, plan_map

__all__ = ["BuildOptions", "plan_map", "wants_index", "write_map"]   # write_map(plan_map(refs, out, BuildOptions()))


def wants_index(given: str | None, n_refs: int) -> bool:
    """Whether a map of ``n_refs`` places gets an index (``BuildOptions.index``: ivf, none; not given: at
    ``IVF_MIN_REFS`` places or more)."""
    return given == "ivf" or (given is None and n_refs >= IVF_MIN_REFS)


def write_map(plan: MapPlan | MapInputs, progress: Progress | None = None) -> str:
    """Build the planned map and write it (and the codebook, if asked) atomically; returns a one-line summary.
    A plan is taken in first (``gather``; its scratch removed at the end). The drives are described and
    encoded one after another, as one route for the codebook fit. A new map holds the map's writer lock
    (``one_writer.writer_lock``: one writer at a time) from the start: a second build of that file is refused in
    one line before its work, never silently replaced. An append takes it only at the end, to read the map
    again, so that a concurrent append that finished meanwhile is kept, and to replace it."""
    with gather(plan) if isinstance(plan, MapPlan) else contextlib.nullcontext(plan) as inputs:
        with writer_lock(inputs.plan.out, wait=False) if inputs.plan.base is None else contextlib.nullcontext():
            return _write_map(inputs, progress)


def _write_map(inputs: MapInputs, progress: Progress | None) -> str:
    plan, o = inputs.plan, inputs.plan.options
    names = [n for d in inputs.drives for n in d.place_names()]
    size = {}
    grey = GreyFrames.of(inputs.front)   # a folder's image named by its path, a bag's frame by its name
    shown = [str(f) if d.names is None else n for d in inputs.drives for f, n in zip(d.files, d.place_names())]
    try:
        if inputs.drives[0].descriptors is None and inputs.files:   # what localize compares its frames with
            first = load_image(inputs.files[0])
            grey.see(first, shown[0])
            height, width = first.shape[:2]
            size = {"frame_size": [int(width), int(height)]}
        if inputs.drives[0].descriptors is not None:
            place_map = map_from_descriptors([d.descriptors for d in inputs.drives], names,
                                             [str(d.source) for d in inputs.drives], plan.storage)
        else:
            elsewhere = None if o.ray is None else partial(encode_on_ray, o.ray)
            place_map = build_map(inputs.files, inputs.front, plan.encoding, plan.given, plan.settings,
                                  o.batch_size, o.svm, plan.storage, progress=progress, elsewhere=elsewhere,
                                  seen=lambda i, image: grey.see(image, shown[i]))
    finally:
        inputs.close()
    choice = {"model_choice": inputs.model_choice} if inputs.model_choice is not None else {}
    meta = {k: v for k, v in (place_map.meta | size | choice).items() if k != "refs_folder"} | \
        ({"refs_folder": str(plan.drives[0].source)} if len(plan.drives) == 1 else {})
    place_map = replace(place_map, names=names, meta=meta, positions=inputs.positions, drives=inputs.drive_list())
    with writer_lock(plan.out) if plan.base is not None else contextlib.nullcontext():
        if plan.base is not None:
            base = load_map(plan.out, mmap=True)
            if not base.encoder.same_as(plan.base.encoder) or base.fingerprint != plan.base.fingerprint:
                raise InputError("{out}: replaced meanwhile by a map with another codebook or front end; nothing "
                                 "appended (run {opt.append} again)", out=plan.out)
            place_map = base.repacked(plan.storage).extended(place_map)
        kept = "ivf" if plan.base is not None and plan.base.index is not None else None   # an indexed map stays so
        if wants_index(o.index or kept, len(place_map.names)):
            place_map = place_map.repacked(plan.storage)
            place_map = replace(place_map, index=fit_ivf(place_map.stored, seed=o.seed))
        save_map(place_map, plan.out, plan.storage)
    if o.save_codebook:
        place_map.encoder.save(o.save_codebook, {k: place_map.meta.get(k) for k in
                                                 ("features", "features_fingerprint", "model_sha256")})
    return _summary_line(inputs, place_map)


def _summary_line(inputs: MapInputs, place_map: PlaceMap) -> str:
    """``wrote OUT: N references ..., D-dim STORAGE FRONT + ENCODING encodings ...``."""
    plan = inputs.plan
    how = "fitted on the references" if plan.given is None else "the map's" if plan.base else "given"
    book = f", {place_map.encoder.n_components}-entry codebook ({how})" if place_map.encoder.needs_fit else ""
    policy = (place_map.features.get("params") or {}).get("resize")
    how_resized = f" (frames resized by {policy})" if policy not in (None, "stretch") else ""
    count = sum(d.count for d in inputs.drives)
    drives = f" in {len(place_map.drives)} drives" if len(place_map.drives) > 1 else ""
    appended = f" ({count} in {len(inputs.drives)} drive{'s' if len(inputs.drives) > 1 else ''} appended)" \
        if plan.base else ""
    return (f"wrote {plan.out}: {len(place_map.names)} references{drives}{appended}, "
            f"{place_map.stored.shape[1]}-dim {plan.storage} {place_map.features['name']}{how_resized} + "
            f"{place_map.encoder.name} encodings{book}{', an SVM per place' if place_map.svm is not None else ''}")
