"""The build-map command as library functions: ``plan_map`` decides every default and checks every option
against the others, the references and the files before any work; ``write_map`` does the work. The CLI
and the tools call these two, so each default lives here once."""
from __future__ import annotations

import tempfile
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from vpr_edge.frames.bags import bag_positions, extract_images, is_bag
from vpr_edge.encoders import ENCODERS, Encoder, FitSettings, load_codebook
from vpr_edge.encoders.registry import DEFAULT_ENCODING
from vpr_edge.errors import VprError, warn
from vpr_edge.features import FrontEnd, make_front_end
from vpr_edge.features.choice import bundled_for_sha256, model_for_frame
from vpr_edge.features.cnn import model_from_env
from vpr_edge.features.conventions import GivenConventions
from vpr_edge.features.registry import DEFAULT_FRONT_END
from vpr_edge.files import check_not_input, check_writable, writer_lock
from vpr_edge.frames.images import list_images, load_image, read_stamps
from vpr_edge.index.encodings import DEFAULT_STORAGE
from vpr_edge.encoders.flat import Flatten
from vpr_edge.features.descriptors import GivenDescriptors
from vpr_edge.frames.descriptors import is_descriptor_file, read_descriptors
from vpr_edge.map.build import Progress, build_map, check_codebook_fits, map_from_descriptors
from vpr_edge.map.front import map_front_end
from vpr_edge.map.io import load_map, save_map
from vpr_edge.map.model import PlaceMap
from vpr_edge.positions import Positions, from_exif, from_gpx, require_gpxpy
from vpr_edge.positions import read_csv as read_positions
from vpr_edge.threads import use_threads



@dataclass(frozen=True)
class BuildOptions:
    """build-map's options; None = not given (the default applies, or with ``append`` the map's own)."""

    features: str | None = None
    encoding: str | None = None
    model: Path | None = None
    resize: str | None = None
    codebook: Path | None = None
    components: int | None = None
    pca_dim: int | None = None
    whiten: bool | None = None
    alpha: float | None = None
    tfidf: bool | None = None
    max_descriptors: int | None = None
    fit_iterations: int | None = None
    svm: bool = False
    seed: int = 0
    save_codebook: Path | None = None
    storage: str | None = None
    positions: str | None = None     # a CSV file, or "exif" for the images' GPS tags
    timestamps: Path | None = None   # a folder's frames' times (frame,stamp CSV), for --positions track.gpx
    topic: str | None = None         # refs is a ROS bag: its image topic
    positions_topic: str | None = None   # ... and its NavSatFix / Odometry topic
    append: bool = False
    inputs: GivenConventions = GivenConventions()   # a model without vpr_edge metadata: its input conventions
    batch_size: int = 8
    threads: int = 0


@dataclass
class MapPlan:
    """What ``write_map`` will do: the reference ``files``, the ``front`` end, the encoder (``given``: a
    codebook or the appended map's; None: fitted on the references), the fit ``settings``, the storage, and
    with ``append`` the map ``base`` the references go after."""

    refs: Path
    out: Path
    files: list[Path]
    front: FrontEnd
    encoding: str
    given: Encoder | None
    settings: FitSettings
    storage: str
    options: BuildOptions
    base: PlaceMap | None = None
    codebook_meta: dict = field(default_factory=dict)
    positions: Positions | None = None
    names: list[str] | None = None           # the references' names when not their files' (a bag's BAG#N)
    scratch: tempfile.TemporaryDirectory | None = None   # where a bag's images were extracted
    model_choice: str | None = None          # why this bundled model (the camera's frame size), when chosen
    descriptors: np.ndarray | None = None    # REFS is a descriptor file: its (R, D) vectors (memory-mapped)


def _fit_options(o: BuildOptions) -> dict:
    return {"--components": o.components, "--pca-dim": o.pca_dim, "--whiten/--no-whiten": o.whiten,
            "--max-descriptors": o.max_descriptors, "--fit-iterations": o.fit_iterations, "--tfidf": o.tfidf}


def _check_options(refs: Path, out: Path, o: BuildOptions, bag: bool, gpx: bool) -> None:
    """Options that contradict each other, or the kind of ``refs`` (a folder or a bag)."""
    fit_options = _fit_options(o)
    fixed = f"--codebook {o.codebook}" if o.codebook else \
        f"--append (the map {out} has its codebook)" if o.append else None
    if o.append:
        given_opts = [k for k, v in (("--codebook", o.codebook), ("--alpha", o.alpha), ("--features", o.features),
                                     ("--resize", o.resize), ("--encoding", o.encoding), ("--svm", o.svm or None))
                      if v is not None] + o.inputs.options()
        if given_opts:
            raise VprError(f"{o.codebook or out}: --append describes and encodes as the map does; drop "
                           f"{', '.join(given_opts)}")
    if fixed and any(v is not None for v in fit_options.values()):
        given_opts = ", ".join(k for k, v in fit_options.items() if v is not None)
        raise VprError(f"{given_opts}: options for fitting a codebook, but {fixed} is given")
    if not bag and (o.topic or o.positions_topic):
        raise VprError(f"{refs}: --topic and --positions-topic apply to a ROS bag or MCAP file")
    if o.positions and o.positions_topic:
        raise VprError(f"--positions {o.positions} and --positions-topic {o.positions_topic}: give one")
    if bag and o.positions == "exif":
        raise VprError(f"{refs}: --positions exif reads image files; a bag's positions come from --positions-topic")
    if gpx and not bag and o.timestamps is None:
        raise VprError(f"{o.positions}: a GPX track is matched to the frames by time: give --timestamps "
                       f"FILE (frame,stamp in Unix seconds) for the folder {refs}")
    if o.timestamps is not None and bag:
        raise VprError(f"{o.timestamps}: a bag's images carry their own stamps; drop --timestamps")
    if o.timestamps is not None and not gpx:
        raise VprError(f"{o.timestamps}: --timestamps serves --positions TRACK.gpx; nothing else uses it here")


def _check_outputs(refs: Path, out: Path, o: BuildOptions) -> None:
    """The outputs can be written and are none of the inputs."""
    for target in (out, o.save_codebook):
        if target:
            check_writable(target)
    # (the map --append reads is also the one it replaces: its own input, by design)
    check_not_input({"--out": out, "--save-codebook": o.save_codebook},
                    [refs, o.codebook, o.model, None if o.positions in (None, "exif") else o.positions,
                     o.timestamps])


def _folder_positions(files: list[Path], o: BuildOptions, gpx: bool) -> Positions | None:
    """A folder's references' positions from --positions (a CSV, a GPX track with --timestamps, or exif)."""
    if o.positions == "exif":
        return from_exif(files)
    if gpx:
        return from_gpx(o.positions, np.asarray(read_stamps(o.timestamps, [f.name for f in files])))
    if o.positions is not None:
        return read_positions(o.positions, [f.name for f in files])
    return None


def _check_appended_positions(base: PlaceMap, positions: Positions | None, given: bool, out: Path,
                              where: str) -> None:
    """Appended references have positions exactly when the map has, in its frame."""
    if (base.positions is None) == given:
        raise VprError(f"{out}: the map has positions: give --positions for the appended references"
                       if base.positions is not None else
                       f"{out}: the map has no positions; --positions cannot be given to --append")
    if positions is not None:
        base.positions.check_frame(positions, where)


def _warn_inapplicable(enc_name: str, o: BuildOptions) -> None:
    """Options given that the encoding does not use: a warning each, then ignored."""
    if not ENCODERS[enc_name].needs_fit:
        for k, v in _fit_options(o).items():
            if v is not None:
                warn(f"{k} does not apply to encoding {enc_name}; ignored")
    if o.tfidf is not None and enc_name != "bow" and ENCODERS[enc_name].needs_fit:
        warn("--tfidf/--no-tfidf applies to encoding bow only; ignored")
    if o.alpha is not None and enc_name not in ("ifv", "vlad"):
        warn(f"--alpha does not apply to encoding {enc_name}; ignored")


def _fit_settings(o: BuildOptions) -> FitSettings:
    """The codebook fit: build-map's options over ``FitSettings``' defaults (--pca-dim 0: no PCA)."""
    d = FitSettings()
    pca_dim = d.pca_dim if o.pca_dim is None else None if o.pca_dim == 0 else o.pca_dim
    return FitSettings(o.components or d.n_components, pca_dim, d.whiten if o.whiten is None else o.whiten,
                       d.alpha if o.alpha is None else o.alpha, o.max_descriptors or d.max_descriptors,
                       o.fit_iterations or d.iterations, o.seed, bool(o.tfidf))


def _plan_descriptors(refs: Path, out: Path, o: BuildOptions) -> MapPlan:
    """``plan_map`` for a descriptor file (``.npy``, hloc ``.h5``): the places are its vectors, described and
    encoded elsewhere, so the options of the image pipeline are refused; positions match the file's names."""
    image_only = [k for k, v in (("--features", o.features), ("--model", o.model), ("--resize", o.resize),
                                 ("--codebook", o.codebook), ("--save-codebook", o.save_codebook),
                                 ("--topic", o.topic), ("--positions-topic", o.positions_topic),
                                 ("--timestamps", o.timestamps), ("--svm", o.svm or None),
                                 ("--alpha", o.alpha), *_fit_options(o).items()) if v is not None]
    image_only += o.inputs.options()
    if o.encoding not in (None, "none"):
        image_only.append(f"--encoding {o.encoding}")
    if o.positions == "exif":
        image_only.append("--positions exif")
    if image_only:
        raise VprError(f"{refs}: global descriptors are described and encoded already; drop "
                       f"{', '.join(image_only)}")
    _check_outputs(refs, out, o)
    values, names = read_descriptors(refs)
    positions = read_positions(o.positions, names) if o.positions else None
    base = load_map(out, mmap=True) if o.append else None
    front = GivenDescriptors(int(values.shape[1]))
    if base is not None:
        _check_appended_positions(base, positions, positions is not None, out, str(o.positions))
        if base.fingerprint != front.fingerprint:
            raise VprError(f"{refs}: descriptors of {front.dim} dims cannot extend {out}, a map of "
                           f"{base.features.get('name')} {base.stored.shape[1]}-dim encodings")
    storage = o.storage or (base.stored.storage if base else DEFAULT_STORAGE)
    return MapPlan(refs, out, [], front, "none", Flatten(front.dim, 1), _fit_settings(o), storage, o, base,
                   positions=positions, names=names, descriptors=values)


def plan_map(refs: Path, out: Path, o: BuildOptions) -> MapPlan:
    """Every check that can be made before the work (VprError, one line), and every default decided."""
    from vpr_edge.encoders.fit import require_sklearn

    if is_descriptor_file(refs):
        return _plan_descriptors(refs, out, o)
    bag = is_bag(refs)
    gpx = o.positions is not None and o.positions.lower().endswith(".gpx")
    _check_options(refs, out, o, bag, gpx)
    _check_outputs(refs, out, o)
    files = [] if bag else list_images(refs)
    if gpx:
        require_gpxpy(o.positions)
    base = load_map(out, mmap=True) if o.append else None
    positions = None if bag else _folder_positions(files, o, gpx)
    if base is not None:
        _check_appended_positions(base, positions, positions is not None or bool(o.positions or o.positions_topic),
                                  out, str(o.positions))
    given, cb_meta = load_codebook(o.codebook) if o.codebook else (None, {})
    if given is not None and o.encoding is not None and o.encoding != given.name:
        raise VprError(f"{o.codebook}: codebook is for encoding {given.name}, not --encoding {o.encoding}")
    ort_threads = use_threads(o.threads)
    front_name = o.features or (cb_meta.get("features") or {}).get("name", DEFAULT_FRONT_END)
    if o.resize is not None and front_name != "cnn":   # (with --append, --resize was refused above)
        raise VprError(f"--resize applies to the cnn front end, not {front_name}")
    if o.inputs.given and (front_name != "cnn" or (o.model is None and model_from_env() is None)):
        raise VprError(f"{', '.join(o.inputs.options())}: input conventions of a model given with --model "
                       f"(the cnn front end)")
    model, choice = o.model, None
    by_camera = front_name == "cnn" and base is None and model is None and model_from_env() is None
    if by_camera and given is not None:   # the bundled model the codebook was fitted with, if it is one
        model = bundled_for_sha256(cb_meta.get("features_fingerprint") or cb_meta.get("model_sha256"))
    elif by_camera and not bag:
        model, choice = _camera_model(files[0])
    spec = {"params": {"resize": o.resize}} if o.resize else None
    if base is not None:
        front = map_front_end(base, out, o.model, ort_threads)
    else:   # a bag's frames are seen only once extracted: its model is chosen then (the same front end)
        front = make_front_end(front_name, model, ort_threads, spec=spec, conventions=o.inputs)
    enc_name = base.encoder.name if base else given.name if given else o.encoding or default_encoding(front)
    if front.is_global and base is None and (enc_name != "none" or given is not None):
        drop = f"--codebook {o.codebook}" if given is not None else f"--encoding {enc_name}"
        raise VprError(f"{front.identity().get('model_path', front.name)}: a global-descriptor model gives one descriptor an image, stored as it "
                       f"is (encoding none, no codebook): drop {drop}")
    _warn_inapplicable(enc_name, o)
    if (given is None and base is None and ENCODERS[enc_name].needs_fit) or o.svm:
        require_sklearn()
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
    storage = o.storage or (base.stored.storage if base else DEFAULT_STORAGE)
    names = scratch = None
    if bag:   # the work starts here: the bag's images are decoded once, into a scratch folder
        scratch = tempfile.TemporaryDirectory(prefix="vpr-edge-bag-")
        files, names, stamps = extract_images(refs, o.topic, Path(scratch.name))
        if by_camera and given is None:
            model, choice = _camera_model(files[0])
            front = make_front_end(front_name, model, ort_threads, spec=spec)
        if o.positions_topic:
            positions = bag_positions(refs, o.positions_topic, stamps)
        elif gpx:
            positions = from_gpx(o.positions, stamps)
        elif o.positions:
            positions = read_positions(o.positions, names)
        if base is not None and positions is not None:
            base.positions.check_frame(positions, str(refs))
    return MapPlan(refs, out, files, front, enc_name, given, _fit_settings(o), storage, o, base, cb_meta,
                   positions, names, scratch, choice)


def default_encoding(front: FrontEnd) -> str:
    """The encoding a new map of ``front`` gets: ``none`` for a global-descriptor model (its output is the
    place's vector), else ``DEFAULT_ENCODING``."""
    return "none" if front.is_global else DEFAULT_ENCODING


def _camera_model(first: Path) -> tuple[Path, str]:
    """The bundled model for the references' camera, judged by the first reference (``features.choice``),
    and the line a map records of the choice."""
    height, width = load_image(first).shape[:2]
    model = model_for_frame(width, height)
    return model, f"camera {width}x{height}: {model.name}"


def write_map(plan: MapPlan, progress: Progress | None = None) -> str:
    """Build the planned map and write it (and the codebook, if asked) atomically; returns a one-line summary.
    The references are described and encoded first; then, holding the map's writer lock (``files.writer_lock``:
    one writer at a time), an appended map is read again, so that a concurrent ``--append`` that finished
    meanwhile is kept, and the result replaces it."""
    o = plan.options
    try:
        if plan.descriptors is not None:
            place_map = map_from_descriptors(plan.descriptors, plan.names, str(plan.refs), plan.storage)
        else:
            place_map = build_map(plan.files, plan.front, plan.encoding, plan.given, plan.settings, o.batch_size,
                                  o.svm, plan.storage, progress=progress)
    finally:
        if plan.scratch is not None:
            plan.scratch.cleanup()
    place_map = replace(place_map, positions=plan.positions)
    if plan.model_choice is not None:
        place_map = replace(place_map, meta=place_map.meta | {"model_choice": plan.model_choice})
    if plan.names is not None:
        place_map = replace(place_map, names=plan.names, meta=place_map.meta | {"refs_folder": str(plan.refs)})
    with writer_lock(plan.out):
        if plan.base is not None:
            base = load_map(plan.out, mmap=True)
            if not base.encoder.same_as(plan.base.encoder) or base.fingerprint != plan.base.fingerprint:
                raise VprError(f"{plan.out}: replaced meanwhile by a map with another codebook or front end; "
                               f"nothing appended (run --append again)")
            place_map = base.repacked(plan.storage).extended(place_map)
        save_map(place_map, plan.out, plan.storage)
    if o.save_codebook:
        place_map.encoder.save(o.save_codebook, {k: place_map.meta.get(k) for k in
                                                 ("features", "features_fingerprint", "model_sha256")})
    how = "fitted on the references" if plan.given is None else "the map's" if plan.base else "given"
    book = f", {place_map.encoder.n_components}-entry codebook ({how})" if place_map.encoder.needs_fit else ""
    policy = (place_map.features.get("params") or {}).get("resize")
    how_resized = f" (frames resized by {policy})" if policy not in (None, "stretch") else ""
    appended = f" ({len(plan.files)} appended)" if plan.base else ""
    return (f"wrote {plan.out}: {len(place_map.names)} references{appended}, "
            f"{place_map.stored.shape[1]}-dim {plan.storage} {place_map.features['name']}{how_resized} + "
            f"{place_map.encoder.name} encodings{book}{', an SVM per place' if place_map.svm is not None else ''}")


def summary(path: Path) -> dict:
    """``vpr-edge info``: a map's size and settings as JSON-ready data (its metadata, names said once)."""
    pm = load_map(path, mmap=True)
    meta = {k: v for k, v in pm.meta.items() if k not in ("names", "n_refs", "dim")}
    route = {"route": pm.positions.summary()} if pm.positions is not None else {}
    here = {}
    if pm.features.get("name") == "cnn":
        try:
            front = map_front_end(pm, path, precision="auto")
            here = {"precision_auto_here": {k: v for k, v in front.runs().items() if k != "name"}}
        except VprError as e:
            here = {"precision_auto_here": {"error": str(e)}}
    return {"references": len(pm.names), "first": pm.names[0], "last": pm.names[-1],
            "encoding_dims": int(pm.stored.shape[1]), "bytes_per_place": pm.stored.bytes_per_place,
            "size_mb": round(path.stat().st_size / 1e6, 2)} | meta | route | here
