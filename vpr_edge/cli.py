"""Command line: ``vpr-edge build-map``, ``localize``, ``evaluate`` and ``info``."""
from __future__ import annotations

import contextlib
import csv
import json
import os
import sys
import time
from collections.abc import Callable, Iterator
from enum import Enum
from pathlib import Path
from typing import IO, Optional

import numpy as np
import typer

from vpr_edge import __version__
from vpr_edge.compact import STORAGES
from vpr_edge.encoders import ENCODERS
from vpr_edge.features import FRONT_ENDS, make_front_end
from vpr_edge.errors import VprError, os_error_line, warn
from vpr_edge.extract import RESIZE
from vpr_edge.images import Frame, list_images, load_image, open_stream
from vpr_edge.api import Localizer, Match, encode_frames
from vpr_edge.mapfile import FIT_DESCRIPTORS, FIT_ITERATIONS, PlaceMap, build_map
from vpr_edge.matchers import MATCHERS, Matcher, get_matcher, param_key
from vpr_edge.store import atomic_output, check_writable
from vpr_edge.threads import use_threads

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  rich_markup_mode=None, context_settings={"help_option_names": ["-h", "--help"],
                                                           "max_content_width": 100})


def _version(value: bool) -> None:
    if value:
        typer.echo(f"vpr-edge {__version__}")
        raise typer.Exit()


@app.callback()
def _main(version: bool = typer.Option(False, "--version", callback=_version, is_eager=True,
                                       help="Print the version and exit.")) -> None:
    """Visual place recognition on a CPU: build a map of reference images, then localise a stream of frames
    against it (ONNX features, Improved Fisher Vectors, sequence matching)."""


ModeOpt = Enum("ModeOpt", {name: name for name in MATCHERS}, type=str)  # type: ignore[misc]
StorageOpt = Enum("StorageOpt", {name: name for name in STORAGES}, type=str)  # type: ignore[misc]
FrontOpt = Enum("FrontOpt", {name: name for name in FRONT_ENDS}, type=str)  # type: ignore[misc]
ResizeOpt = Enum("ResizeOpt", {name: name for name in RESIZE}, type=str)  # type: ignore[misc]
EncodingOpt = Enum("EncodingOpt", {name: name for name in ENCODERS}, type=str)  # type: ignore[misc]


class VariantOpt(str, Enum):
    distance = "distance"
    similarity = "similarity"


class FeaturesOpt(str, Enum):
    map = "map"
    pixels = "pixels"



class FormatOpt(str, Enum):
    csv = "csv"
    jsonl = "jsonl"


@contextlib.contextmanager
def _user_errors() -> Iterator[None]:
    """Turn VprError into one line on stderr and exit code 2; Ctrl-C into exit code 130."""
    try:
        yield
    except (VprError, ValueError) as e:
        typer.echo(f"vpr-edge: error: {e}", err=True)
        raise typer.Exit(2) from None
    except BrokenPipeError:  # the reader went away (``| head``): stop quietly, as Unix tools do
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        raise typer.Exit(1) from None
    except OSError as e:  # disk full, permission lost mid-run: name the file and the reason
        typer.echo(f"vpr-edge: error: {os_error_line(e)}", err=True)
        raise typer.Exit(2) from None
    except KeyboardInterrupt:
        typer.echo("vpr-edge: interrupted", err=True)
        raise typer.Exit(130) from None


_MODEL_HELP = ("ONNX feature model exported by vpr_edge_export (default: $VPR_EDGE_MODEL if set, else the "
               "bundled EfficientNet-Lite0 tap).")
_THREADS_HELP = ("Threads for onnxruntime and NumPy's BLAS together, so the two pools never oversubscribe "
                 "the cores (0 = one per core).")


@app.command("build-map")
def build_map_cmd(
    refs: Path = typer.Argument(..., help="Folder of reference images, taken in file-name order."),
    out: Path = typer.Option(..., "--out", "-o", help="Map file to write (.npz); written atomically."),
    features: Optional[FrontOpt] = typer.Option(None, metavar="FRONT_END", help="Local descriptors: "
                                                + ", ".join(FRONT_ENDS) + " (default cnn). README, Front ends."),
    encoding: Optional[EncodingOpt] = typer.Option(None, metavar="ENCODING", help="How an image's local "
                                                   "descriptors become one vector: " + ", ".join(ENCODERS)
                                                   + " (default ifv, the thesis's). README, Encodings."),
    model: Optional[Path] = typer.Option(None, help=_MODEL_HELP + " cnn only."),
    resize: Optional[ResizeOpt] = typer.Option(None, help="cnn only: how images are brought to the model's "
                                               "input: " + "; ".join(f"{k}: {v}" for k, v in RESIZE.items())
                                               + ". Recorded in the map; queries are resized the same way."),
    codebook: Optional[Path] = typer.Option(
        None, help="Reuse this codebook (.npz from --save-codebook) instead of fitting one on the references."),
    components: Optional[int] = typer.Option(None, min=1, help="Codebook size when fitting: GMM components "
                                             "(fv, ifv) or k-means centres (bow, vlad); default 128, as the thesis."),
    pca_dim: Optional[int] = typer.Option(None, min=1, help="Reduce descriptors to this many dims by PCA "
                                                            "before the codebook (default: no PCA)."),
    whiten: Optional[bool] = typer.Option(None, "--whiten/--no-whiten", help="Whiten the PCA output "
                                          "(default: whiten; with --pca-dim only)."),
    alpha: Optional[float] = typer.Option(None, min=0.0, max=1.0, help="Signed power normalisation exponent "
                                          "of ifv and vlad (default 0.5; 1 = off)."),
    tfidf: Optional[bool] = typer.Option(None, "--tfidf/--no-tfidf", help="bow: weight words by their inverse "
                                         "document frequency over the references (default off)."),
    max_descriptors: Optional[int] = typer.Option(None, min=1, help="Local descriptors sampled to fit the "
                                                                    f"codebook (default {FIT_DESCRIPTORS})."),
    fit_iterations: Optional[int] = typer.Option(None, min=1, help="EM / k-means iterations at most when "
                                                 f"fitting (default {FIT_ITERATIONS})."),
    svm: bool = typer.Option(False, "--svm", help="Also train one linear SVM per place on the reference "
                             "encodings (for localize/evaluate --mode svm; doubles the map's size)."),
    seed: int = typer.Option(0, help="Random seed for sampling and fitting."),
    save_codebook: Optional[Path] = typer.Option(None, help="Also write the codebook to this .npz file."),
    storage: Optional[StorageOpt] = typer.Option(None, help="How the map stores reference encodings: int8 "
                                                 "with a scale per row (default; a quarter of float32's bytes, "
                                                 "R@1 within 0.005 of float32 on both shared datasets), float16 "
                                                 "or float32. With --append: the map's own unless given."),
    append: bool = typer.Option(False, "--append", help="Add REFS' images after the references of the map "
                                "at --out, described and encoded as its own (the map is replaced "
                                "atomically); the route grows without refitting."),
    batch_size: int = typer.Option(8, min=1, help="Images per model run."),
    threads: int = typer.Option(0, min=0, help=_THREADS_HELP),
) -> None:
    """Build a map from a folder of reference images: describe each (a CNN tap by default, or a handcrafted
    front end), fit the codebook unless --codebook is given, encode every reference (an Improved Fisher
    Vector by default), optionally train an SVM per place, and write one map file."""
    from vpr_edge.encoders import FitSettings, load_codebook
    from vpr_edge.encoders.fit import require_sklearn

    with _user_errors():
        # --- everything that can be checked before the work ---
        fit_options = {"--components": components, "--pca-dim": pca_dim, "--whiten/--no-whiten": whiten,
                       "--max-descriptors": max_descriptors, "--fit-iterations": fit_iterations, "--tfidf": tfidf}
        fixed = f"--codebook {codebook}" if codebook else f"--append (the map {out} has its codebook)" if append \
            else None
        if append:
            given_opts = [o for o, v in (("--codebook", codebook), ("--alpha", alpha), ("--features", features),
                                         ("--resize", resize),
                                         ("--encoding", encoding), ("--svm", svm or None)) if v is not None]
            if given_opts:
                raise VprError(f"{codebook or out}: --append describes and encodes as the map does; drop "
                               f"{', '.join(given_opts)}")
        if fixed and any(v is not None for v in fit_options.values()):
            given_opts = ", ".join(k for k, v in fit_options.items() if v is not None)
            raise VprError(f"{given_opts}: options for fitting a codebook, but {fixed} is given")
        if whiten is not None and pca_dim is None:
            warn("--whiten/--no-whiten applies only with --pca-dim; ignored")
        for target in (out, save_codebook):
            if target:
                check_writable(target)
        if save_codebook and save_codebook.resolve() == out.resolve():
            raise VprError(f"{out}: --out and --save-codebook name the same file")
        files = list_images(refs)
        base = PlaceMap.load(out, mmap=True) if append else None
        given = cb_meta = None
        if codebook:
            given, cb_meta = load_codebook(codebook)
            if encoding is not None and encoding.value != given.name:
                raise VprError(f"{codebook}: codebook is for encoding {given.name}, not --encoding {encoding.value}")
        enc_name = base.encoder.name if base else given.name if given else encoding.value if encoding else "ifv"
        if not ENCODERS[enc_name].needs_fit:
            for k, v in fit_options.items():
                if v is not None:
                    warn(f"{k} does not apply to encoding {enc_name}; ignored")
        if tfidf is not None and enc_name != "bow" and ENCODERS[enc_name].needs_fit:
            warn(f"--tfidf/--no-tfidf applies to encoding bow only; ignored")
        if alpha is not None and enc_name not in ("ifv", "vlad"):
            warn(f"--alpha does not apply to encoding {enc_name}; ignored")
        if (given is None and base is None and ENCODERS[enc_name].needs_fit) or svm:
            require_sklearn()
        use = use_threads(threads)
        front_name = features.value if features else (cb_meta or {}).get("features", {}).get("name", "cnn")
        if resize is not None and front_name != "cnn":   # (with --append, --resize was refused above)
            raise VprError(f"--resize applies to the cnn front end, not {front_name}")
        front = base.front_end(out, model, use) if base else make_front_end(
            front_name, model, use, spec={"params": {"resize": resize.value}} if resize else None)
        if enc_name == "none" and front.n_local is None:
            raise VprError(f"encoding none needs a front end with a fixed grid of descriptors; {front.name} detects "
                           f"keypoints (a varying number per image): choose bow, vlad, fv or ifv")
        if base is not None:
            given = base.encoder
        elif given is not None:
            recorded = cb_meta.get("features_fingerprint") or cb_meta.get("model_sha256")
            described = (cb_meta.get("features") or {}).get("name", "cnn")
            # an int8 model may reuse the codebook of the fp32 model it was quantised from
            fits = (None, front.fingerprint, getattr(front, "source_fingerprint", None))
            if described != front.name or recorded not in fits:
                raise VprError(f"{codebook}: codebook was fitted on {described} descriptors "
                               f"({str(recorded)[:12]}), not on this {front.name} front end's "
                               f"({front.fingerprint[:12]}){'; another model' if front.name == 'cnn' else ''}")
            if given.input_dim != front.dim:  # build_map checks too; here the message can name the file
                raise VprError(f"{codebook}: codebook expects {given.input_dim}-dim descriptors but "
                               f"the {front.name} front end gives {front.dim}")
            if alpha is not None:
                given = given.with_alpha(alpha)
        settings = FitSettings(components or 128, pca_dim, True if whiten is None else whiten,
                               0.5 if alpha is None else alpha, max_descriptors or FIT_DESCRIPTORS,
                               fit_iterations or FIT_ITERATIONS, seed, bool(tfidf))

        # --- the work ---
        kept = storage.value if storage else base.stored.storage if base else "int8"
        with typer.progressbar(length=len(files), label="extracting", file=sys.stderr,
                               hidden=not sys.stderr.isatty()) as bar:
            place_map = build_map(files, front, enc_name, given, settings, batch_size, svm, kept,
                                  progress=bar.update)
        if base is not None:
            place_map = base.repacked(kept).extended(place_map)
        place_map.save(out, kept)
        if save_codebook:
            place_map.encoder.save(save_codebook, {k: place_map.meta.get(k) for k in
                                                   ("features", "features_fingerprint", "model_sha256")})
        how = "fitted on the references" if given is None else "the map's" if base else "given"
        book = f", {place_map.encoder.n_components}-entry codebook ({how})" if place_map.encoder.needs_fit else ""
        policy = (place_map.features.get("params") or {}).get("resize")
        how_resized = f" (frames resized by {policy})" if policy not in (None, "stretch") else ""
        typer.echo(f"wrote {out}: {len(place_map.names)} references{f' ({len(files)} appended)' if base else ''}, "
                   f"{place_map.stored.shape[1]}-dim {kept} {place_map.features['name']}{how_resized} + "
                   f"{place_map.encoder.name} encodings{book}"
                   f"{', an SVM per place' if place_map.svm is not None else ''}", err=True)


@contextlib.contextmanager
def _writing(where: str) -> Iterator[None]:
    """A failed write (disk full, device gone) becomes one line naming ``where``; a closed pipe passes."""
    try:
        yield
    except BrokenPipeError:
        raise
    except OSError as e:
        raise VprError(f"{where}: cannot write results ({e.strerror or e})") from None


def _results_writer(fmt: str, stream: IO[str], where: str) -> Callable[[Match], None]:
    """Write the header now; return a function writing one result line and flushing it (a line per frame,
    as it happens)."""
    if fmt == "csv":
        w = csv.writer(stream, lineterminator="\n")
        with _writing(where):
            w.writerow(["frame_index", "frame", "ref_index", "ref", "score", "lost"])

        def line(m: Match) -> None:
            w.writerow([m.frame_index, m.frame, m.ref_index, m.ref, f"{m.score:.6f}", int(m.lost)])
    else:
        def line(m: Match) -> None:
            stream.write(json.dumps(m.__dict__ | {"score": round(m.score, 6)}) + "\n")

    def write(m: Match) -> None:
        with _writing(where):
            line(m)
            stream.flush()
    return write


def _params_for(name: str, given: dict) -> dict:
    """The options the user gave that matcher ``name`` takes; a warning for each it ignores."""
    matcher = get_matcher(name)
    for k in sorted(k for k, v in given.items() if v not in (None, False) and k not in matcher.params):
        warn(f"--{k.replace('_', '-')} does not apply to mode {name}; ignored")
    return {k: v for k, v in given.items() if v is not None and k in matcher.params}


_PARAM_HELP = ("Set one of the matcher's parameters (repeatable), e.g. --param bias=1.6 --param lock=6: "
               "calibrating the stream's lost state on a drive of your own route (README: Calibrating the lost "
               "state). "
               "Names and defaults: vpr_edge/matchers/registry.py (an unknown KEY's error lists them); "
               "evaluate --json records the values run.")


def _with_param_options(matcher: Matcher, params: dict, items: list[str]) -> dict:
    """``params`` (from the named options) plus ``--param KEY=VALUE`` items for ``matcher``; ValueError for an
    item it does not take, VprError for a key given both ways."""
    extra = matcher.parse_params(items)
    both = sorted(set(extra) & set(params))
    if both:
        raise VprError(f"--param {both[0]} repeats --{both[0].replace('_', '-')}; give it once")
    return params | extra


def _param_options_for_all(matchers: dict[str, Matcher], items: list[str]) -> dict[str, Matcher]:
    """Each of ``matchers`` with the ``--param`` items whose key it has; VprError for a key none has (and
    ``parse_params``'s ValueError for a value one refuses)."""
    keys = [param_key(item) for item in items]
    for item, key in zip(items, keys):
        if not any(key in m.params for m in matchers.values()):
            raise VprError(f"--param {item!r}: none of the modes {','.join(matchers)} has a parameter {key!r}")
    return {name: m.with_params(**m.parse_params([i for i, k in zip(items, keys) if k in m.params]))
            for name, m in matchers.items()}


_MODE_HELP = ("Matcher. Online (a result per frame): " + ", ".join(n for n, m in MATCHERS.items() if m.online)
              + ". Offline (results after the last frame): " + ", ".join(n for n, m in MATCHERS.items()
                                                                         if not m.online)
              + ". What each does: README, Matchers.")


@app.command("localize")
def localize_cmd(
    map_path: Path = typer.Option(..., "--map", "-m", help="Map file written by build-map."),
    stream: str = typer.Option(..., "--stream", "-s", metavar="SOURCE",
                               help="Folder of frames (file-name order), a video file, "
                                    "a camera (0, 1, ... or /dev/video0) or a network stream (rtsp://...)."),
    model: Optional[Path] = typer.Option(None, help="ONNX feature model; must be the map's model (default: "
                                         "$VPR_EDGE_MODEL if set, else the file the map was built with if it "
                                         "still exists, else the bundled one)."),
    mode: ModeOpt = typer.Option("stream", metavar="MATCHER", help=_MODE_HELP),
    variant: Optional[VariantOpt] = typer.Option(None, help="DTW modes: distance (minimise summed 1 - cosine, "
                                                 "default) or similarity (maximise summed cosine, the thesis)."),
    open_ends: Optional[bool] = typer.Option(None, "--open-ends/--fixed-ends", help="DTW modes: let the path "
                                             "start and end anywhere, 0-4 references per frame (dtw-open)."),
    decay: Optional[float] = typer.Option(None, min=0.01, max=0.999, help="stream / stream-dtw: each frame "
                                          "discounts the past by this factor (about 1/(1-decay) frames kept)."),
    window: Optional[int] = typer.Option(None, min=0, help="stream: local search, references either side of a "
                                         "firm lock read per frame, on routes over 4x this (default %d; 0 = "
                                         "every reference every frame)." % MATCHERS["stream"].params["window"]),
    min_confidence: Optional[float] = typer.Option(
        None, help="Frames scoring below this are reported lost (ref_index -1). Default: the mode's own "
                   "(stream: %.1f; other modes: never lost)." % MATCHERS["stream"].min_confidence),
    param: Optional[list[str]] = typer.Option(None, "--param", metavar="KEY=VALUE", help=_PARAM_HELP),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="Write results here instead of stdout "
                                       "(written to a temporary file, renamed when the stream is done)."),
    fmt: Optional[FormatOpt] = typer.Option(None, "--format", help="csv or jsonl (default: from --out's "
                                            "suffix, csv on stdout)."),
    batch_size: int = typer.Option(1, min=1, help="Frames per model run (1 = lowest latency)."),
    threads: int = typer.Option(0, min=0, help=_THREADS_HELP),
) -> None:
    """Localise every frame of a stream against a map. One line per frame: frame index, frame name,
    matched reference index and name (-1 and empty when lost), score (higher = more confident), lost (0/1).
    Undecodable frames are reported on stderr and skipped."""
    with _user_errors():
        if out:
            check_writable(out)
        suffix_fmt = {".csv": "csv", ".jsonl": "jsonl", ".json": "jsonl"}.get(out.suffix.lower()) if out else None
        if fmt and suffix_fmt and fmt.value != suffix_fmt:
            raise VprError(f"{out}: --format {fmt.value} contradicts the file's {out.suffix} suffix")
        params = _params_for(mode.value, {"variant": variant.value if variant else None, "open_ends": open_ends,
                                          "decay": decay, "window": window})
        params = _with_param_options(get_matcher(mode.value), params, param or [])
        frames, count = open_stream(stream)
        localizer = Localizer(map_path, model=model, mode=mode.value, params=params,
                              min_confidence=min_confidence, threads=threads)
        chosen = fmt.value if fmt else (suffix_fmt or "csv")
        skipped = 0

        def skip(frame: Frame) -> None:
            nonlocal skipped
            skipped += 1
            typer.echo(f"\nvpr-edge: warning: {frame.error}; frame skipped", err=True)  # \n: off the bar

        with contextlib.ExitStack() as stack:
            if out:
                sink = stack.enter_context(open(stack.enter_context(atomic_output(out)), "w", newline=""))
            else:
                sink = sys.stdout
            write = _results_writer(chosen, sink, str(out or "stdout"))
            written = 0
            with typer.progressbar(length=count or 0, label="localizing", file=sys.stderr,
                                   hidden=count is None or not sys.stderr.isatty()) as bar:
                for match in localizer.run(frames, batch_size, skip):
                    write(match)
                    written += 1
                    bar.update(1)
            if written == 0:
                raise VprError(f"{stream}: none of its frames could be decoded")
        if skipped:
            typer.echo(f"vpr-edge: {skipped} undecodable frame(s) skipped", err=True)


def _load_truth(gt: Optional[Path], positions: Optional[tuple[Path, Path]], radius: float):
    """Ground truth from --gt (CSV or .npy matrix) or --gt-positions; exactly one must be given."""
    from vpr_edge import groundtruth

    if (gt is None) == (positions is None):
        raise VprError("give ground truth: --gt FILE (.csv or .npy) or --gt-positions REFS.csv QUERIES.csv")
    if positions is not None:
        return groundtruth.from_positions(positions[0], positions[1], radius), None
    if gt.suffix.lower() == ".npy":
        return groundtruth.load_matrix(gt), np.load(gt, mmap_mode="r").shape
    return groundtruth.load_csv(gt), None


def _load_similarity(path: Path) -> np.ndarray:
    try:
        sim = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as e:
        raise VprError(f"{path}: not a readable .npy matrix ({str(e).splitlines()[0][:100]})") from None
    if sim.ndim != 2 or 0 in sim.shape or not np.issubdtype(sim.dtype, np.number):
        raise VprError(f"{path}: similarity must be a non-empty 2-D numeric (queries x references) matrix, "
                       f"got shape {sim.shape} {sim.dtype}")
    if not np.isfinite(sim).all():
        raise VprError(f"{path}: similarity matrix holds NaN or infinite values")
    return sim.astype(np.float64)


@app.command("evaluate")
def evaluate_cmd(
    map_path: Optional[Path] = typer.Option(None, "--map", "-m", help="Map from build-map: the queries are "
                                            "encoded with its model and codebook."),
    queries: Optional[Path] = typer.Option(None, "--queries", "-q", help="Query frames: a folder (file-name "
                                           "order) or a video. Row i of the ground truth is frame i."),
    similarity: Optional[Path] = typer.Option(None, "--similarity", help="Evaluate a (Q, R) float .npy "
                                              "similarity matrix instead (rows = queries, higher = more "
                                              "alike), e.g. from another tool's descriptors; no model needed."),
    refs: Optional[Path] = typer.Option(None, "--refs", help="With --features pixels: the reference folder."),
    features: FeaturesOpt = typer.Option(FeaturesOpt.map, help="map: the map's CNN features and encoding; "
                                         "pixels: SeqSLAM's front end (grey, 64x32, patch-normalised, "
                                         "mean absolute difference), from --refs and --queries, no map."),
    gt: Optional[Path] = typer.Option(None, "--gt", help="Ground truth: the project's CSV 'query,references' "
                                      "(space-separated reference indices, empty = place not in the map) or a "
                                      "boolean (Q, R) .npy matrix (VPR_Tutorial's GThard/GTsoft)."),
    gt_positions: Optional[tuple[Path, Path]] = typer.Option(
        None, "--gt-positions", help="Ground truth from positions: REFS.csv QUERIES.csv with columns x,y "
                                     "(metres) or lat,lon (degrees); see --radius."),
    radius: float = typer.Option(25.0, min=0.0, help="With --gt-positions: references within this many "
                                                    "metres of a query are correct."),
    modes: Optional[str] = typer.Option(None, help="Comma-separated matchers to run on the same "
                                        "similarity matrix: " + ", ".join(MATCHERS) + " (default: all that "
                                        "apply; svm with a map built with --svm)."),
    tolerance: int = typer.Option(1, min=0, help="Frames of slack around the true references (thesis: 1)."),
    window: Optional[int] = typer.Option(None, min=0, help="stream: local search window, as localize's "
                                         "(default %d; 0 = every reference every frame)."
                                         % MATCHERS["stream"].params["window"]),
    min_confidence: Optional[float] = typer.Option(None, help="Lost threshold for modes with a lost state "
                                                   "(default: each mode's own)."),
    param: Optional[list[str]] = typer.Option(None, "--param", metavar="KEY=VALUE",
                                              help=_PARAM_HELP + " Applies to every chosen mode that has KEY."),
    json_out: Optional[Path] = typer.Option(None, "--json", help="Write the figures as JSON here."),
    plot_out: Optional[Path] = typer.Option(None, "--plot", help="Write all modes' PR curves to this PNG "
                                            "(needs matplotlib: the plot extra)."),
    save_similarity: Optional[Path] = typer.Option(None, help="Also save the (Q, R) similarity matrix (.npy)."),
    model: Optional[Path] = typer.Option(None, help="With --map: the map's model, if not where it was."),
    batch_size: int = typer.Option(8, min=1, help="Frames per model run."),
    threads: int = typer.Option(0, min=0, help=_THREADS_HELP),
) -> None:
    """Measure matchers against ground truth: recall@1/5/10, the precision-recall curve with AUC (thesis
    eq. 5.1) and AP (eq. 5.2), precision at 100% recall, recall at 100% precision, median error in frames,
    the share of frames reported lost, and matching time per frame. All modes run on one similarity matrix:
    from --map and --queries, from --features pixels with --refs and --queries, or from --similarity."""
    from vpr_edge import report
    from vpr_edge.evaluate import evaluate_mode

    with _user_errors():
        # --- everything that can be checked before the work ---
        sources = [similarity is not None, map_path is not None, features == FeaturesOpt.pixels]
        if sum(sources) != 1:
            raise VprError("give one source: --similarity S.npy, or --map MAP --queries Q, or --features "
                           "pixels --refs R --queries Q")
        if similarity is None and queries is None:
            raise VprError("--queries is needed with --map or --features pixels")
        if features == FeaturesOpt.pixels and refs is None:
            raise VprError("--features pixels needs --refs (the reference folder)")
        chosen = [m.strip() for m in modes.split(",") if m.strip()] if modes is not None else \
            [n for n, m in MATCHERS.items() if m.scores == "cosine"]
        matchers = {name: get_matcher(name) for name in chosen}
        if not matchers:
            raise VprError("--modes names no matcher")
        if window is not None:
            if not any("window" in m.params for m in matchers.values()):
                warn(f"--window does not apply to modes {','.join(matchers)}; ignored")
            matchers = {n: m.with_params(window=window) if "window" in m.params else m for n, m in matchers.items()}
        if param:
            matchers = _param_options_for_all(matchers, param)
        for target in (json_out, plot_out, save_similarity):
            if target:
                check_writable(target)
        if plot_out:
            report.require_matplotlib()
        truth, gt_shape = _load_truth(gt, gt_positions, radius)
        truth_src = gt or gt_positions[0]
        use_threads(threads)

        # --- the similarity matrix ---
        encode_ms = float("nan")
        svm_sim = None
        if "svm" in matchers and map_path is None:
            raise VprError("mode svm needs --map (a map built with build-map --svm)")
        if similarity is not None:
            sim = _load_similarity(similarity)
        else:
            frames, count = open_stream(queries)
            if count is not None and count != len(truth):
                raise VprError(f"{queries}: {count} frames but the ground truth {truth_src} has {len(truth)} rows")
            kept: list[int] = []

            def skip(frame: Frame) -> None:
                typer.echo(f"vpr-edge: warning: {frame.error}; frame skipped (and its ground-truth row)", err=True)

            t0 = time.perf_counter()
            if features == FeaturesOpt.pixels:
                from vpr_edge.pixels import pixel_descriptor, sad_similarity

                ref_desc = np.stack([pixel_descriptor(load_image(f)) for f in list_images(refs)])
                t0 = time.perf_counter()
                qd = []
                for frame in frames:
                    if frame.image is None:
                        skip(frame)
                        continue
                    kept.append(frame.index)
                    qd.append(pixel_descriptor(frame.image))
                sim = sad_similarity(np.stack(qd), ref_desc).astype(np.float64) if qd else np.zeros((0, 0))
            else:
                loc = Localizer(map_path, model=model, mode="single", threads=threads)
                if modes is None and loc.map.svm is not None:
                    matchers["svm"] = get_matcher("svm")
                if "svm" in matchers and loc.map.svm is None:
                    raise VprError(f"{map_path}: mode svm needs a map built with build-map --svm")
                enc = []
                for frame, e in encode_frames(frames, loc.map, loc.front, batch_size, skip):
                    kept.append(frame.index)
                    enc.append(e)
                sim = loc.similarity(np.stack(enc)).astype(np.float64) if enc else np.zeros((0, 0))
                if "svm" in matchers and enc:
                    svm_sim = loc.map.scores(np.stack(enc), "svm").astype(np.float64)
            if not kept:
                raise VprError(f"{queries}: none of its frames could be decoded")
            encode_ms = 1e3 * (time.perf_counter() - t0) / len(kept)
            if max(kept) >= len(truth):
                raise VprError(f"{queries}: {max(kept) + 1} frames but the ground truth {truth_src} has "
                               f"{len(truth)} rows")
            truth = truth[kept]
        if len(truth) != sim.shape[0]:
            raise VprError(f"{truth_src}: ground truth has {len(truth)} rows but there are {sim.shape[0]} queries")
        if gt_shape is not None and gt_shape[1] != sim.shape[1]:
            raise VprError(f"{truth_src}: ground-truth matrix has {gt_shape[1]} references, the similarity "
                           f"matrix {sim.shape[1]}")
        if truth.max() >= sim.shape[1]:
            raise VprError(f"{truth_src}: names reference {int(truth.max())} but there are only "
                           f"{sim.shape[1]} references")
        if save_similarity:
            with atomic_output(save_similarity) as tmp, open(tmp, "wb") as f:
                np.save(f, sim.astype(np.float32), allow_pickle=False)

        # --- the matchers ---
        sims = {"cosine": sim, "svm": svm_sim}
        reports = {name: evaluate_mode(m, sims[m.scores], truth, tolerance, min_confidence)
                   for name, m in matchers.items()}
        n_mapped = int((truth >= 0).any(axis=1).sum())
        typer.echo(f"{sim.shape[0]} queries ({n_mapped} of mapped places), {sim.shape[1]} references; "
                   f"correct within {tolerance} frame(s); encoding "
                   f"{'-' if encode_ms != encode_ms else f'{encode_ms:.1f}'} ms/frame")
        typer.echo(report.table(reports))
        if json_out:
            report.write_json(json_out, sim.shape[0], sim.shape[1], reports, tolerance)
        if plot_out:
            report.plot(plot_out, reports, f"{queries or similarity} ({sim.shape[0]} queries, {sim.shape[1]} refs)")


@app.command("info")
def info_cmd(map_path: Path = typer.Argument(..., help="Map file written by build-map.")) -> None:
    """Describe a map: references, encoding size, codebook, model and settings (JSON on stdout)."""
    with _user_errors():
        pm = PlaceMap.load(map_path, mmap=True)
        meta = {k: v for k, v in pm.meta.items() if k not in ("names", "n_refs", "dim")}  # said once, below
        summary = {"references": len(pm.names), "first": pm.names[0], "last": pm.names[-1],
                   "encoding_dims": int(pm.stored.shape[1]), "size_mb": round(map_path.stat().st_size / 1e6, 2)}
        typer.echo(json.dumps(summary | meta, indent=1, sort_keys=True))


# click's UsageError and ClickException, whether typer vendors click or depends on it
_USAGE_ERROR, _CLICK_ERROR = typer.BadParameter.__mro__[1:3]


def main() -> None:
    """Console-script entry point: a usage error (unknown option, missing argument) is one line on stderr,
    ``vpr-edge: error: COMMAND: problem (see 'COMMAND -h')``, exit code 2, like every other refusal."""
    try:
        rc = app(prog_name="vpr-edge", standalone_mode=False)
    except _USAGE_ERROR as e:
        if type(e).__name__ == "NoArgsIsHelpError":          # bare `vpr-edge` or `vpr-edge CMD`: the help
            e.show()
            sys.exit(e.exit_code)
        where = e.ctx.command_path if e.ctx is not None else "vpr-edge"
        print(f"vpr-edge: error: {where}: {e.format_message().rstrip('.')} (see '{where} -h')", file=sys.stderr)
        sys.exit(2)
    except _CLICK_ERROR as e:
        print(f"vpr-edge: error: {e.format_message()}", file=sys.stderr)
        sys.exit(e.exit_code)
    except typer.Abort:
        print("vpr-edge: aborted", file=sys.stderr)
        sys.exit(1)
    sys.exit(rc if isinstance(rc, int) else 0)


if __name__ == "__main__":
    main()
