"""A map's build planned (``plan_map``): every default decided and every option checked against the others,
the drives and the files, before any work and without doing any. The plan lists the folders' images and reads
what it checks (a codebook, the map appended to, descriptor files' headers, the model's metadata, the images'
headers for their sizes), but decodes no image, extracts no bag, reads no positions and picks no model by
the camera: ``map.make`` does those, then builds. A wrong option is an ``InputError`` naming the options as
``BuildOptions`` calls them; the CLI says them as its flags."""
from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from vpr_edge.encoders import ENCODERS, Encoder, FitSettings, load_codebook
from vpr_edge.encoders.flat import Flatten
from vpr_edge.encoders.registry import DEFAULT_ENCODING
from vpr_edge.errors import InputError, Message, VprError, said, warn
from vpr_edge.features import FrontEnd, make_front_end
from vpr_edge.features.choice import bundled_for_sha256
from vpr_edge.features.cnn import model_from_env
from vpr_edge.features.descriptors import GivenDescriptors
from vpr_edge.features.registry import DEFAULT_FRONT_END
from vpr_edge.files.checks import check_not_input, check_writable
from vpr_edge.frames.bags import is_bag
from vpr_edge.frames.descriptor_files import descriptor_dims, is_descriptor_file
from vpr_edge.frames.images import check_frame_sizes, list_images
from vpr_edge.index.encodings import DEFAULT_STORAGE
from vpr_edge.map.build import check_codebook_fits
from vpr_edge.map.drives import check_unique, drive_name
from vpr_edge.map.fleet import check_ray
from vpr_edge.map.front import map_front_end
from vpr_edge.map.io import load_map
from vpr_edge.map.model import PlaceMap
from vpr_edge.map.options import (BuildOptions, convention_inputs, fit_inputs, fit_settings, named, parse_drive,
                                  per_drive)
from vpr_edge.positions import PositionSource
from vpr_edge.threads import use_threads


@dataclass(frozen=True)
class DrivePlan:
    """One drive as planned: its ``name``, where its frames come from (``source``) and what that is (``kind``:
    images, a folder's; bag; descriptors, a file's vectors), a folder's image ``files`` (listed, not read),
    where its positions come from (None: none) and, for a folder matched to a GPX track, its frames' times
    (``timestamps``: a frame,stamp CSV)."""

    name: str
    source: Path
    kind: str
    files: tuple[Path, ...] = ()
    positions: PositionSource | None = None
    timestamps: Path | None = None


@dataclass(frozen=True)
class MapPlan:
    """What the build will do: the ``drives`` (in the order given), the ``front`` end (with ``by_camera``, a
    stand-in of the bundled model chosen once the first frame is seen, ``front_spec`` its record), the
    encoder (``given``: a codebook or the appended map's; None: fitted on the references), the fit
    ``settings``, the storage, and with ``append`` the map ``base`` the drives go after."""

    out: Path
    drives: tuple[DrivePlan, ...]
    front: FrontEnd
    encoding: str
    given: Encoder | None
    settings: FitSettings
    storage: str
    options: BuildOptions
    base: PlaceMap | None = None
    codebook_meta: dict = field(default_factory=dict)
    by_camera: bool = False
    front_spec: dict | None = None
    ort_threads: int = 0


def default_encoding(front: FrontEnd) -> str:
    """The encoding a new map of ``front`` gets: ``none`` for a global-descriptor model (its output is the
    place's vector), else ``DEFAULT_ENCODING``."""
    return "none" if front.is_global else DEFAULT_ENCODING


def _check_options(refs: Path, out: Path, o: BuildOptions, positions: str | None, timestamps: Path | None,
                   bag: bool, gpx: bool) -> None:
    """Options that contradict each other, or the kind of the drive ``refs`` (a folder or a bag) with its
    ``positions`` and ``timestamps``."""
    fit = fit_inputs(o)
    fixed = Message("{opt.codebook} {codebook}", codebook=o.codebook) if o.codebook else \
        Message("{opt.append} (the map {out} has its codebook)", out=out) if o.append else None
    if o.append:
        drop = [k for k, v in (("codebook", o.codebook), ("alpha", o.alpha), ("features", o.features),
                               ("resize", o.resize), ("encoding", o.encoding), ("svm", o.svm or None))
                if v is not None] + convention_inputs(o.inputs)
        if drop:
            raise InputError("{at}: {opt.append} describes and encodes as the map does; drop {drop}",
                             at=o.codebook or out, drop=named(drop))
    if fixed and fit:
        raise InputError("{fit}: options for fitting a codebook, but {fixed} is given", fit=named(fit), fixed=fixed)
    if not bag and (o.topic or o.positions_topic):
        raise InputError("{refs}: {opt.topic} and {opt.positions_topic} apply to a ROS bag or MCAP file", refs=refs)
    if positions and o.positions_topic:
        raise InputError("{opt.positions} {positions} and {opt.positions_topic} {topic}: give one",
                         positions=positions, topic=o.positions_topic)
    if bag and positions == "exif":
        raise InputError("{refs}: {opt.positions} exif reads image files; a bag's positions come from "
                         "{opt.positions_topic}", refs=refs)
    if gpx and not bag and timestamps is None:
        raise InputError("{positions}: a GPX track is matched to the frames by time: give {opt.timestamps} FILE "
                         "(frame,stamp in Unix seconds) for the folder {refs}", positions=positions, refs=refs)
    if timestamps is not None and bag:
        raise InputError("{timestamps}: a bag's images carry their own stamps; drop {opt.timestamps}",
                         timestamps=timestamps)
    if timestamps is not None and not gpx:
        raise InputError("{timestamps}: {opt.timestamps} serves {opt.positions} TRACK.gpx; nothing else uses "
                         "it here", timestamps=timestamps)


def _check_outputs(drives: list[Path], out: Path, o: BuildOptions) -> None:
    """The outputs can be written and are none of the inputs."""
    for target in (out, o.save_codebook):
        if target:
            check_writable(target)
    # (the map an append reads is also the one it replaces: its own input, by design)
    check_not_input({said("{opt.out}"): out, said("{opt.save_codebook}"): o.save_codebook},
                    [*drives, o.codebook, o.model, *[p for p in o.positions if p != "exif"], *o.timestamps])


def _checked_base(specs: list[tuple[str, Path]], out: Path, o: BuildOptions) -> PlaceMap | None:
    """After the outputs are checked: the map ``append`` extends (None without it), and VprError for two
    drives of one name among those given, or beside the appended map's."""
    check_unique([n for n, _ in specs], "the drives given")
    if not o.append:
        return None
    base = load_map(out, mmap=True)
    check_unique(base.drives.names + [n for n, _ in specs], f"{out} and the appended drives")
    return base


def _check_drive_positions(base: PlaceMap | None, drives: Sequence[DrivePlan], given: list[bool], out: Path) -> None:
    """Every drive has positions, or none has; appended drives have them exactly when the map has (their
    frames are checked against the map's once read)."""
    if any(given) and not all(given):
        missing = drives[given.index(False)].name
        raise VprError(f"{drives[given.index(True)].name} has positions, {missing} has none: a map has positions "
                       f"for every drive or for none")
    if base is not None and (base.positions is None) == given[0]:
        raise InputError("{out}: the map has positions: give {opt.positions} for the appended drives"
                         if base.positions is not None else
                         "{out}: the map has no positions; {opt.positions} cannot be given to {opt.append}", out=out)


def _warn_inapplicable(enc_name: str, o: BuildOptions) -> None:
    """Options given that the encoding does not use: a warning each, then ignored."""
    if not ENCODERS[enc_name].needs_fit:
        for label in fit_inputs(o):
            warn(Message("{label} does not apply to encoding {enc}; ignored", label=label, enc=enc_name))
    if o.tfidf is not None and enc_name != "bow" and ENCODERS[enc_name].needs_fit:
        warn(Message("{opt.tfidf}/{opt.no_tfidf} applies to encoding bow only; ignored"))
    if o.alpha is not None and enc_name not in ("ifv", "vlad"):
        warn(Message("{opt.alpha} does not apply to encoding {enc}; ignored", enc=enc_name))


def _plan_descriptors(specs: list[tuple[str, Path]], out: Path, o: BuildOptions) -> MapPlan:
    """``plan_map`` for descriptor files (``.npy``, hloc ``.h5``): the places are their vectors, described and
    encoded elsewhere, so the options of the image pipeline are refused; positions match the files' names."""
    image_only: list[str | Message] = [
        k for k, v in (("features", o.features), ("model", o.model), ("resize", o.resize), ("codebook", o.codebook),
                       ("save_codebook", o.save_codebook), ("topic", o.topic), ("positions_topic", o.positions_topic),
                       ("timestamps", o.timestamps or None), ("svm", o.svm or None), ("alpha", o.alpha))
        if v is not None]
    image_only += fit_inputs(o) + convention_inputs(o.inputs)
    if o.ray is not None:
        image_only.append(Message("{opt.ray} {ray} (descriptor files need no per-frame work)", ray=o.ray))
    if o.encoding not in (None, "none"):
        image_only.append(Message("{opt.encoding} {encoding}", encoding=o.encoding))
    if "exif" in o.positions:
        image_only.append(Message("{opt.positions} exif"))
    if image_only:
        raise InputError("{at}: global descriptors are described and encoded already; drop {drop}",
                         at=specs[0][1], drop=named(image_only))
    _check_outputs([p for _, p in specs], out, o)
    base = _checked_base(specs, out, o)
    drives = tuple(DrivePlan(name, path, "descriptors", positions=PositionSource.given(pos) if pos else None)
                   for (name, path), (pos, _) in zip(specs, per_drive(o, len(specs))))
    _check_drive_positions(base, drives, [d.positions is not None for d in drives], out)
    dims = []
    for d in drives:
        if not d.source.is_file():
            raise VprError(f"{d.source}: no such descriptor file")
        dims.append(descriptor_dims(d.source))
    front = GivenDescriptors(dims[0])
    for d, dim in zip(drives[1:], dims[1:]):
        if dim != front.dim:
            raise VprError(f"{d.source}: descriptors of {dim} dims, {drives[0].source}'s "
                           f"have {front.dim}: the drives of a map come from one network")
    if base is not None and base.fingerprint != front.fingerprint:
        raise VprError(f"{specs[0][1]}: descriptors of {front.dim} dims cannot extend {out}, a map of "
                       f"{base.features.get('name')} {base.stored.shape[1]}-dim encodings")
    storage = o.storage or (base.stored.storage if base else DEFAULT_STORAGE)
    return MapPlan(out, drives, front, "none", Flatten(front.dim, 1), fit_settings(o), storage, o, base)


def plan_map(refs: str | os.PathLike[str] | Sequence[str | os.PathLike[str]], out: Path,
             o: BuildOptions) -> MapPlan:
    """Every check that can be made before the work (VprError, one line; ``InputError`` for options), and
    every default decided. ``refs``: one drive or several (``options.parse_drive``: a folder, video, bag or
    descriptor file, or NAME=PATH), each kept as a drive of its own in the given order."""
    from vpr_edge.encoders.fit import require_sklearn

    given_refs = [refs] if isinstance(refs, (str, os.PathLike)) else list(refs)
    if not given_refs:
        raise VprError("build-map: give at least one drive (a folder of images, a video, a bag or a descriptor file)")
    specs = [(drive_name(str(p), n), p) for n, p in map(parse_drive, given_refs)]
    kinds = {is_descriptor_file(p) for _, p in specs}
    if len(kinds) > 1:
        vectors = next(p for _, p in specs if is_descriptor_file(p))
        images = next(p for _, p in specs if not is_descriptor_file(p))
        raise VprError(f"{images}, {vectors}: the drives of a map are all descriptor files or all images "
                       f"(folders, videos, bags), not both")
    if kinds == {True}:
        return _plan_descriptors(specs, out, o)
    per = per_drive(o, len(specs))
    bags = [is_bag(p) for _, p in specs]
    sources = [PositionSource.of_bag(path, o.positions_topic) if bag and o.positions_topic else
               PositionSource.given(pos) if pos else None for (_, path), (pos, _), bag in zip(specs, per, bags)]
    for (_, path), (pos, ts), bag, source in zip(specs, per, bags, sources):
        _check_options(path, out, o, pos, ts, bag, source is not None and source.kind == "gpx")
    _check_outputs([p for _, p in specs], out, o)
    base = _checked_base(specs, out, o)
    drives = tuple(DrivePlan(name, path, "bag" if bag else "images", () if bag else tuple(list_images(path)),
                             source, ts) for (name, path), (_, ts), bag, source in zip(specs, per, bags, sources))
    for d in drives:
        if d.positions is not None:
            d.positions.require()
    _check_drive_positions(base, drives, [d.positions is not None for d in drives], out)
    given, cb_meta = load_codebook(o.codebook) if o.codebook else (None, {})
    if given is not None and o.encoding is not None and o.encoding != given.name:
        raise InputError("{codebook}: codebook is for encoding {name}, not {opt.encoding} {encoding}",
                         codebook=o.codebook, name=given.name, encoding=o.encoding)
    ort_threads = use_threads(o.threads)
    front_name = o.features or (cb_meta.get("features") or {}).get("name", DEFAULT_FRONT_END)
    if o.resize is not None and front_name != "cnn":   # (with append, resize was refused above)
        raise InputError("{opt.resize} applies to the cnn front end, not {front}", front=front_name)
    if o.inputs.given and (front_name != "cnn" or (o.model is None and model_from_env() is None)):
        raise InputError("{given}: input conventions of a model given with {opt.model} (the cnn front end)",
                         given=named(convention_inputs(o.inputs)))
    model = o.model
    by_camera = front_name == "cnn" and base is None and model is None and model_from_env() is None
    if by_camera and given is not None:   # the bundled model the codebook was fitted with, if it is one
        model = bundled_for_sha256(cb_meta.get("features_fingerprint") or cb_meta.get("model_sha256"))
    camera_picks = by_camera and given is None
    spec = {"params": {"resize": o.resize}} if o.resize else None
    if base is not None:
        front = map_front_end(base, out, o.model, ort_threads)
    else:   # by the camera: a stand-in (the bundled default) until the first frame is seen
        front = make_front_end(front_name, model, ort_threads, spec=spec, conventions=o.inputs)
    enc_name = base.encoder.name if base else given.name if given else o.encoding or default_encoding(front)
    if front.is_global and base is None and (enc_name != "none" or given is not None):
        drop = Message("{opt.codebook} {codebook}", codebook=o.codebook) if given is not None else \
            Message("{opt.encoding} {encoding}", encoding=enc_name)
        raise InputError("{model}: a global-descriptor model gives one descriptor an image, stored as it is "
                         "(encoding none, no codebook): drop {drop}",
                         model=front.identity().get("model_path", front.name), drop=drop)
    _warn_inapplicable(enc_name, o)
    if (given is None and base is None and ENCODERS[enc_name].needs_fit) or o.svm:
        require_sklearn()
    if o.ray is not None:
        if enc_name == "bow" and o.tfidf and given is None:
            raise InputError("{opt.ray} {ray}: {opt.tfidf} needs every reference's words at once to fit; build it "
                             "without {opt.ray}, or give {opt.codebook}", ray=o.ray)
        check_ray(o.ray)
    if enc_name == "none" and front.n_local is None:
        raise VprError(f"encoding none needs a front end with a fixed grid of descriptors; {front.name} detects "
                       f"keypoints (a varying number per image): choose bow, vlad, fv or ifv")
    if base is not None:
        given = base.encoder
    elif given is not None:
        check_codebook_fits(given, cb_meta, front, str(o.codebook))
        if o.alpha is not None:
            given = given.with_alpha(o.alpha)
    if front.is_global and given is None:
        given = Flatten(front.dim, 1)       # the descriptor L2-normalised: nothing to fit
    for d in drives:   # (a bag's frames are checked once extracted: map.gather)
        if d.kind == "images":
            check_frame_sizes(d.source, d.files, o.strict, resized_to=resized_to(front))
    storage = o.storage or (base.stored.storage if base else DEFAULT_STORAGE)
    return MapPlan(out, drives, front, enc_name, given, fit_settings(o), storage, o, base, cb_meta,
                   camera_picks, spec, ort_threads)


def resized_to(front: FrontEnd) -> str:
    """What every frame is resized to before ``front`` describes it, in words (for the mixed-sizes warning)."""
    return "the model's input" if front.name == "cnn" else f"the {front.name} front end's input"
