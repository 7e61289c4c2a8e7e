"""The build-map command as library functions: ``plan_map`` decides every default and checks every option
against the others, the references and the files before any work; ``write_map`` does the work. The CLI
and the tools call these two, so each default lives here once."""
from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path

import numpy as np

from vpr_edge.frames.bags import extract_images, is_bag
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
from vpr_edge.index.ivf import IVF_MIN_REFS, fit_ivf
from vpr_edge.map.fleet import check_ray, encode_on_ray
from vpr_edge.map.drives import Drives, check_unique, drive_name, spans_of
from vpr_edge.map.build import Progress, build_map, check_codebook_fits, map_from_descriptors
from vpr_edge.map.front import map_front_end
from vpr_edge.map.io import load_map, save_map
from vpr_edge.map.model import PlaceMap
from vpr_edge.positions import Positions
from vpr_edge.positions.bag import bag_positions
from vpr_edge.positions.csv import read_csv as read_positions
from vpr_edge.positions.exif import from_exif
from vpr_edge.positions.gpx import from_gpx, require_gpxpy
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
    positions: tuple[str, ...] = ()      # per drive a CSV or GPX file, or ("exif",): the images' GPS tags
    timestamps: tuple[Path, ...] = ()    # per drive its frames' times (frame,stamp CSV), for --positions track.gpx
    topic: str | None = None         # refs is a ROS bag: its image topic
    positions_topic: str | None = None   # ... and its NavSatFix / Odometry topic
    append: bool = False
    inputs: GivenConventions = GivenConventions()   # a model without vpr_edge metadata: its input conventions
    batch_size: int = 8
    threads: int = 0
    ray: str | None = None     # describe and encode on this Ray cluster (local, auto, HOST:PORT, ray://HOST:PORT)
    index: str | None = None   # ivf, none; None: ivf on maps of IVF_MIN_REFS places or more (index.ivf)

    def __post_init__(self) -> None:   # one value given as such: one drive's
        for key in ("positions", "timestamps"):
            value = getattr(self, key)
            if value is None or isinstance(value, (str, os.PathLike)):
                object.__setattr__(self, key, () if value is None else (value,))


@dataclass
class DrivePlan:
    """One drive as ``write_map`` will take it: its ``name``, where its frames come from (``source``), its
    image files (a bag's once extracted), their names where not the files' (a bag's BAG#N, a descriptor
    file's rows), its positions, its frames' times (seconds; None: not known) and, for a descriptor file, its
    (n, D) vectors (memory-mapped)."""

    name: str
    source: Path
    files: list[Path] = field(default_factory=list)
    names: list[str] | None = None
    positions: Positions | None = None
    stamps: np.ndarray | None = None
    descriptors: np.ndarray | None = None

    @property
    def count(self) -> int:
        return len(self.descriptors) if self.descriptors is not None else len(self.files)

    def place_names(self) -> list[str]:
        return list(self.names) if self.names is not None else [f.name for f in self.files]


@dataclass
class MapPlan:
    """What ``write_map`` will do: the ``drives`` (``DrivePlan``, in the order given), the ``front`` end, the
    encoder (``given``: a codebook or the appended map's; None: fitted on the references), the fit
    ``settings``, the storage, and with ``append`` the map ``base`` the drives go after."""

    out: Path
    drives: list[DrivePlan]
    front: FrontEnd
    encoding: str
    given: Encoder | None
    settings: FitSettings
    storage: str
    options: BuildOptions
    base: PlaceMap | None = None
    codebook_meta: dict = field(default_factory=dict)
    scratch: tempfile.TemporaryDirectory | None = None   # where bags' images were extracted
    model_choice: str | None = None          # why this bundled model (the camera's frame size), when chosen

    @property
    def files(self) -> list[Path]:
        """Every drive's image files, drive after drive."""
        return [f for d in self.drives for f in d.files]

    @property
    def refs(self) -> Path:
        """The first drive's source (a map of one drive: its folder or file)."""
        return self.drives[0].source

    @property
    def positions(self) -> Positions | None:
        """Every drive's positions, drive after drive (None: the drives have none)."""
        if self.drives[0].positions is None:
            return None
        out = self.drives[0].positions
        for d in self.drives[1:]:
            out = out.concat(d.positions)
        return out

    def drive_list(self) -> Drives:
        return Drives.of([d.name for d in self.drives], [d.count for d in self.drives],
                         [str(d.source) for d in self.drives], [spans_of(d.stamps) for d in self.drives])


def _fit_options(o: BuildOptions) -> dict:
    return {"--components": o.components, "--pca-dim": o.pca_dim, "--whiten/--no-whiten": o.whiten,
            "--max-descriptors": o.max_descriptors, "--fit-iterations": o.fit_iterations, "--tfidf": o.tfidf}


def parse_drive(text: str | os.PathLike[str]) -> tuple[str | None, Path]:
    """A REFS argument -> (the drive's name if given, its path): ``NAME=PATH`` names a drive (a path that
    exists as given is taken as a path, whatever it holds)."""
    text = os.fspath(text)
    name, sep, path = text.partition("=")
    if not sep or Path(text).exists() or not name:
        return None, Path(text)
    return name, Path(path)


def _per_drive(o: BuildOptions, n: int) -> list[tuple[str | None, Path | None]]:
    """Each drive's --positions and --timestamps: as many as drives, in their order; one --positions exif for
    them all; none. VprError otherwise."""
    def spread(values: tuple, option: str) -> list:
        if not values:
            return [None] * n
        if len(values) == n:
            return list(values)
        if option == "--positions" and values == ("exif",):
            return ["exif"] * n
        raise VprError(f"{option} {values[0]}: given {len(values)} time(s) for {n} drives: give one per drive, "
                       f"in the drives' order" + (" (or --positions exif for all)" if option == "--positions" else ""))
    return list(zip(spread(o.positions, "--positions"), spread(o.timestamps, "--timestamps")))


def _check_options(refs: Path, out: Path, o: BuildOptions, positions: str | None, timestamps: Path | None,
                   bag: bool, gpx: bool) -> None:
    """Options that contradict each other, or the kind of the drive ``refs`` (a folder or a bag) with its
    ``positions`` and ``timestamps``."""
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
    if positions and o.positions_topic:
        raise VprError(f"--positions {positions} and --positions-topic {o.positions_topic}: give one")
    if bag and positions == "exif":
        raise VprError(f"{refs}: --positions exif reads image files; a bag's positions come from --positions-topic")
    if gpx and not bag and timestamps is None:
        raise VprError(f"{positions}: a GPX track is matched to the frames by time: give --timestamps "
                       f"FILE (frame,stamp in Unix seconds) for the folder {refs}")
    if timestamps is not None and bag:
        raise VprError(f"{timestamps}: a bag's images carry their own stamps; drop --timestamps")
    if timestamps is not None and not gpx:
        raise VprError(f"{timestamps}: --timestamps serves --positions TRACK.gpx; nothing else uses it here")


def _check_outputs(drives: list[Path], out: Path, o: BuildOptions) -> None:
    """The outputs can be written and are none of the inputs."""
    for target in (out, o.save_codebook):
        if target:
            check_writable(target)
    # (the map --append reads is also the one it replaces: its own input, by design)
    check_not_input({"--out": out, "--save-codebook": o.save_codebook},
                    [*drives, o.codebook, o.model, *[p for p in o.positions if p != "exif"], *o.timestamps])


def _folder_positions(files: list[Path], positions: str | None, timestamps: Path | None,
                      gpx: bool) -> tuple[Positions | None, np.ndarray | None]:
    """A folder's references' positions from its --positions (a CSV, a GPX track with --timestamps, or exif),
    and their times where --timestamps gives them."""
    if positions == "exif":
        return from_exif(files), None
    if gpx:
        stamps = np.asarray(read_stamps(timestamps, [f.name for f in files]))
        return from_gpx(positions, stamps), stamps
    if positions is not None:
        return read_positions(positions, [f.name for f in files]), None
    return None, None


def _checked_base(specs: list[tuple[str, Path]], out: Path, o: BuildOptions) -> PlaceMap | None:
    """After the outputs are checked: the map ``--append`` extends (None without it), and VprError for two
    drives of one name among those given, or beside the appended map's."""
    check_unique([n for n, _ in specs], "the drives given")
    if not o.append:
        return None
    base = load_map(out, mmap=True)
    check_unique(base.drives.names + [n for n, _ in specs], f"{out} and the appended drives")
    return base


def _check_drive_positions(base: PlaceMap | None, drives: list[DrivePlan], given: list[bool], out: Path) -> None:
    """Every drive has positions, or none has; appended drives have them exactly when the map has, in its frame."""
    if any(given) and not all(given):
        missing = drives[given.index(False)].name
        raise VprError(f"{drives[given.index(True)].name} has positions, {missing} has none: a map has positions "
                       f"for every drive or for none")
    if base is not None and (base.positions is None) == given[0]:
        raise VprError(f"{out}: the map has positions: give --positions for the appended drives"
                       if base.positions is not None else
                       f"{out}: the map has no positions; --positions cannot be given to --append")
    first = base.positions if base is not None else next((d.positions for d in drives if d.positions), None)
    for d in drives:
        if first is not None and d.positions is not None:
            first.check_frame(d.positions, str(d.source))


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


def _plan_descriptors(specs: list[tuple[str, Path]], out: Path, o: BuildOptions) -> MapPlan:
    """``plan_map`` for descriptor files (``.npy``, hloc ``.h5``): the places are their vectors, described and
    encoded elsewhere, so the options of the image pipeline are refused; positions match the files' names."""
    image_only = [k for k, v in (("--features", o.features), ("--model", o.model), ("--resize", o.resize),
                                 ("--codebook", o.codebook), ("--save-codebook", o.save_codebook),
                                 ("--topic", o.topic), ("--positions-topic", o.positions_topic),
                                 ("--timestamps", o.timestamps or None), ("--svm", o.svm or None),
                                 ("--alpha", o.alpha), *_fit_options(o).items()) if v is not None]
    image_only += o.inputs.options()
    if o.ray is not None:
        image_only.append(f"--ray {o.ray} (descriptor files need no per-frame work)")
    if o.encoding not in (None, "none"):
        image_only.append(f"--encoding {o.encoding}")
    if "exif" in o.positions:
        image_only.append("--positions exif")
    if image_only:
        raise VprError(f"{specs[0][1]}: global descriptors are described and encoded already; drop "
                       f"{', '.join(image_only)}")
    _check_outputs([p for _, p in specs], out, o)
    base = _checked_base(specs, out, o)
    drives = []
    for (name, path), (positions, _) in zip(specs, _per_drive(o, len(specs))):
        values, names = read_descriptors(path)
        drives.append(DrivePlan(name, path, names=names, descriptors=values,
                                positions=read_positions(positions, names) if positions else None))
    _check_drive_positions(base, drives, [d.positions is not None for d in drives], out)
    front = GivenDescriptors(int(drives[0].descriptors.shape[1]))
    for d in drives[1:]:
        if d.descriptors.shape[1] != front.dim:
            raise VprError(f"{d.source}: descriptors of {d.descriptors.shape[1]} dims, {drives[0].source}'s "
                           f"have {front.dim}: the drives of a map come from one network")
    if base is not None and base.fingerprint != front.fingerprint:
        raise VprError(f"{specs[0][1]}: descriptors of {front.dim} dims cannot extend {out}, a map of "
                       f"{base.features.get('name')} {base.stored.shape[1]}-dim encodings")
    storage = o.storage or (base.stored.storage if base else DEFAULT_STORAGE)
    return MapPlan(out, drives, front, "none", Flatten(front.dim, 1), _fit_settings(o), storage, o, base)


def plan_map(refs: str | os.PathLike[str] | Sequence[str | os.PathLike[str]], out: Path,
             o: BuildOptions) -> MapPlan:
    """Every check that can be made before the work (VprError, one line), and every default decided.
    ``refs``: one drive or several (``parse_drive``: a folder, video, bag or descriptor file, or NAME=PATH),
    each kept as a drive of its own in the given order."""
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
    per = _per_drive(o, len(specs))
    bags, gpxs = [is_bag(p) for _, p in specs], [pos is not None and pos.lower().endswith(".gpx") for pos, _ in per]
    for (_, path), (pos, ts), bag, gpx in zip(specs, per, bags, gpxs):
        _check_options(path, out, o, pos, ts, bag, gpx)
    _check_outputs([p for _, p in specs], out, o)
    base = _checked_base(specs, out, o)
    drives = [DrivePlan(name, path, [] if bag else list_images(path)) for (name, path), bag in zip(specs, bags)]
    if any(gpxs):
        require_gpxpy(next(pos for pos, _ in per if pos))
    for d, (pos, ts), bag, gpx in zip(drives, per, bags, gpxs):
        if not bag:
            d.positions, d.stamps = _folder_positions(d.files, pos, ts, gpx)
    given_pos = [bool(pos or o.positions_topic) for pos, _ in per]
    _check_drive_positions(base, drives, given_pos, out)
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
    first_image = next((d.files[0] for d in drives if d.files), None)
    if by_camera and given is not None:   # the bundled model the codebook was fitted with, if it is one
        model = bundled_for_sha256(cb_meta.get("features_fingerprint") or cb_meta.get("model_sha256"))
    elif by_camera and first_image is not None:
        model, choice = _camera_model(first_image)
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
    if o.ray is not None:
        if enc_name == "bow" and o.tfidf and given is None:
            raise VprError(f"--ray {o.ray}: --tfidf needs every reference's words at once to fit; build it "
                           f"without --ray, or give --codebook")
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
    storage = o.storage or (base.stored.storage if base else DEFAULT_STORAGE)
    scratch = None
    if any(bags):   # the work starts here: each bag's images are decoded once, into a scratch folder
        scratch = tempfile.TemporaryDirectory(prefix="vpr-edge-bag-")
        for k, (d, (pos, _), bag, gpx) in enumerate(zip(drives, per, bags, gpxs)):
            if bag:
                _extract_bag(d, Path(scratch.name) / str(k), o, pos, gpx, base)
        if by_camera and given is None and first_image is None:
            model, choice = _camera_model(drives[0].files[0])
            front = make_front_end(front_name, model, ort_threads, spec=spec)
    return MapPlan(out, drives, front, enc_name, given, _fit_settings(o), storage, o, base, cb_meta, scratch,
                   choice)


def _extract_bag(d: DrivePlan, folder: Path, o: BuildOptions, positions: str | None, gpx: bool,
                 base: PlaceMap | None) -> None:
    """A bag drive's images decoded into ``folder``, with their names, times and positions (from
    --positions-topic, a GPX track matched by time, or a CSV by name)."""
    folder.mkdir()
    d.files, d.names, stamps = extract_images(d.source, o.topic, folder)
    d.stamps = np.asarray(stamps, np.float64)
    if o.positions_topic:
        d.positions = bag_positions(d.source, o.positions_topic, stamps)
    elif gpx:
        d.positions = from_gpx(positions, d.stamps)
    elif positions:
        d.positions = read_positions(positions, d.names)
    if base is not None and d.positions is not None:
        base.positions.check_frame(d.positions, str(d.source))


def wants_index(given: str | None, n_refs: int) -> bool:
    """Whether a map of ``n_refs`` places gets an index (``--index``: ivf, none; not given: at
    ``IVF_MIN_REFS`` places or more)."""
    return given == "ivf" or (given is None and n_refs >= IVF_MIN_REFS)


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
    The drives are described and encoded first, one after another, as one route for the codebook fit. A new
    map holds the map's writer lock (``files.writer_lock``: one writer at a time) from the start: a second
    build of that file is refused in one line before its work, never silently replaced. An append takes it
    only at the end, to read the map again, so that a concurrent ``--append`` that finished meanwhile is kept,
    and to replace it."""
    with writer_lock(plan.out, wait=False) if plan.base is None else contextlib.nullcontext():
        return _write_map(plan, progress)


def _write_map(plan: MapPlan, progress: Progress | None) -> str:
    o = plan.options
    names = [n for d in plan.drives for n in d.place_names()]
    size = {}
    try:
        if plan.drives[0].descriptors is None and plan.files:   # what localize compares its frames with
            height, width = load_image(plan.files[0]).shape[:2]
            size = {"frame_size": [int(width), int(height)]}
        if plan.drives[0].descriptors is not None:
            place_map = map_from_descriptors([d.descriptors for d in plan.drives], names,
                                             [str(d.source) for d in plan.drives], plan.storage)
        else:
            elsewhere = None if o.ray is None else partial(encode_on_ray, o.ray)
            place_map = build_map(plan.files, plan.front, plan.encoding, plan.given, plan.settings, o.batch_size,
                                  o.svm, plan.storage, progress=progress, elsewhere=elsewhere)
    finally:
        if plan.scratch is not None:
            plan.scratch.cleanup()
    meta = place_map.meta | size | ({"model_choice": plan.model_choice} if plan.model_choice is not None else {})
    meta = {k: v for k, v in meta.items() if k != "refs_folder"} | \
        ({"refs_folder": str(plan.refs)} if len(plan.drives) == 1 else {})
    place_map = replace(place_map, names=names, meta=meta, positions=plan.positions, drives=plan.drive_list())
    with writer_lock(plan.out) if plan.base is not None else contextlib.nullcontext():
        if plan.base is not None:
            base = load_map(plan.out, mmap=True)
            if not base.encoder.same_as(plan.base.encoder) or base.fingerprint != plan.base.fingerprint:
                raise VprError(f"{plan.out}: replaced meanwhile by a map with another codebook or front end; "
                               f"nothing appended (run --append again)")
            place_map = base.repacked(plan.storage).extended(place_map)
        kept = "ivf" if plan.base is not None and plan.base.index is not None else None   # an indexed map stays so
        if wants_index(o.index or kept, len(place_map.names)):
            place_map = place_map.repacked(plan.storage)
            place_map = replace(place_map, index=fit_ivf(place_map.stored, seed=o.seed))
        save_map(place_map, plan.out, plan.storage)
    if o.save_codebook:
        place_map.encoder.save(o.save_codebook, {k: place_map.meta.get(k) for k in
                                                 ("features", "features_fingerprint", "model_sha256")})
    how = "fitted on the references" if plan.given is None else "the map's" if plan.base else "given"
    book = f", {place_map.encoder.n_components}-entry codebook ({how})" if place_map.encoder.needs_fit else ""
    policy = (place_map.features.get("params") or {}).get("resize")
    how_resized = f" (frames resized by {policy})" if policy not in (None, "stretch") else ""
    count = sum(d.count for d in plan.drives)
    drives = f" in {len(place_map.drives)} drives" if len(place_map.drives) > 1 else ""
    appended = f" ({count} in {len(plan.drives)} drive{'s' if len(plan.drives) > 1 else ''} appended)" \
        if plan.base else ""
    return (f"wrote {plan.out}: {len(place_map.names)} references{drives}{appended}, "
            f"{place_map.stored.shape[1]}-dim {plan.storage} {place_map.features['name']}{how_resized} + "
            f"{place_map.encoder.name} encodings{book}{', an SVM per place' if place_map.svm is not None else ''}")


def summary(path: Path) -> dict:
    """``vpr-edge info``: a map's size and settings as JSON-ready data (its metadata, names said once)."""
    pm = load_map(path, mmap=True)
    meta = {k: v for k, v in pm.meta.items() if k not in ("names", "n_refs", "dim")}
    route = {"route": pm.positions.summary()} if pm.positions is not None else {}
    meta["drives"] = pm.drives.meta()
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
