"""``vpr-edge build-map``: options in, ``map.plan.plan_map`` (every check, no work), ``map.gather.gather`` and
``write_map`` (the work) called, a summary line out."""
from __future__ import annotations

import sys
from pathlib import Path
from typing import Optional

import typer

from vpr_edge.cli.common import (MODEL_HELP, THREADS_HELP, EncodingOpt, FrontOpt, LayoutOpt, ResizeOpt, StorageOpt,
                                 app, user_errors)
from vpr_edge.encoders import ENCODERS, FitSettings
from vpr_edge.features import FRONT_ENDS
from vpr_edge.features.conventions import GivenConventions
from vpr_edge.features.resize import RESIZE
from vpr_edge.encoders.base import DEFAULT_PCA_DIM
from vpr_edge.errors import VprError
from vpr_edge.files.checks import output_path
from vpr_edge.encoders.registry import DEFAULT_ENCODING
from vpr_edge.features.registry import DEFAULT_FRONT_END
from vpr_edge.index.encodings import DEFAULT_STORAGE
from vpr_edge.index.ivf import IVF_MIN_REFS
from vpr_edge.map.gather import gather
from vpr_edge.map.make import write_map
from vpr_edge.map.options import BuildOptions
from vpr_edge.map.plan import plan_map

_FIT = FitSettings()


def _value(opt):
    return None if opt is None else opt.value


@app.command("build-map")
def build_map_cmd(
    refs: list[str] = typer.Argument(..., metavar="DRIVE...", help="One or more drives, each kept as a "
                                     "sequence of its own: a folder of reference images (file-name order), a ROS "
                                     "bag / MCAP file with --topic, or a file of global descriptors computed "
                                     "elsewhere (.npy rows, hloc .h5). A drive is named after its folder or file; "
                                     "NAME=PATH names it."),
    out: str = typer.Option(..., "--out", "-o", help="Map file to write (.npz); written atomically, never over "
                            "an input nor inside the reference folder. A symbolic link is written through."),
    features: Optional[FrontOpt] = typer.Option(None, metavar="FRONT_END", help="Local descriptors: "
                                                + ", ".join(FRONT_ENDS) + f" (default {DEFAULT_FRONT_END}). "
                                                "docs/design.md, Front ends."),
    encoding: Optional[EncodingOpt] = typer.Option(None, metavar="ENCODING", help="How an image's local "
                                                   "descriptors become one vector: " + ", ".join(ENCODERS)
                                                   + f" (default {DEFAULT_ENCODING}, the thesis's). "
                                                   "docs/design.md, Encodings."),
    model: Optional[Path] = typer.Option(None, help=MODEL_HELP + " cnn only."),
    resize: Optional[ResizeOpt] = typer.Option(None, help="cnn only: how images are brought to the model's "
                                               "input: " + "; ".join(f"{k}: {v}" for k, v in RESIZE.items())
                                               + ". Recorded in the map; queries are resized the same way."),
    input_size: Optional[str] = typer.Option(None, metavar="WxH", help="A --model without vpr_edge metadata (a "
                                             "network exported elsewhere): its input size in pixels (default: "
                                             "the model's, where fixed). docs/models.md, Your own network."),
    mean: Optional[str] = typer.Option(None, metavar="R,G,B|imagenet", help="A --model without vpr_edge "
                                       "metadata: the mean subtracted per channel, on the [0, 1] pixel scale, in "
                                       "the model's channel order (required for such a model)."),
    std: Optional[str] = typer.Option(None, metavar="R,G,B|imagenet", help="A --model without vpr_edge "
                                      "metadata: the std divided by per channel, on the [0, 1] scale (required "
                                      "for such a model)."),
    bgr: bool = typer.Option(False, "--bgr", help="A --model without vpr_edge metadata takes its channels "
                             "as B, G, R (default R, G, B)."),
    layout: Optional[LayoutOpt] = typer.Option(None, help="A --model without vpr_edge metadata: its input "
                                               "layout, nchw or nhwc (default: read from the model's input "
                                               "shape, nchw if that does not tell)."),
    codebook: Optional[Path] = typer.Option(
        None, help="Reuse this codebook (.npz from --save-codebook) instead of fitting one on the references."),
    components: Optional[int] = typer.Option(None, min=1, help="Codebook size when fitting: GMM components "
                                             "(fv, ifv) or k-means centres (bow, vlad); default "
                                             f"{_FIT.n_components} (the thesis used 128: --components 128 --pca-dim 0)."),
    pca_dim: Optional[int] = typer.Option(None, min=0, help="Reduce descriptors to this many dims by PCA "
                                          f"before the codebook (default {DEFAULT_PCA_DIM} for descriptors "
                                          "of more dims, none for binary ones; 0 = no PCA)."),
    whiten: Optional[bool] = typer.Option(None, "--whiten/--no-whiten", help="Whiten the PCA output "
                                          "(default: whiten)."),
    alpha: Optional[float] = typer.Option(None, min=0.0, max=1.0, help="Signed power normalisation exponent "
                                          f"of ifv and vlad (default {_FIT.alpha}; 1 = off)."),
    tfidf: Optional[bool] = typer.Option(None, "--tfidf/--no-tfidf", help="bow: weight words by their inverse "
                                         "document frequency over the references (default off)."),
    max_descriptors: Optional[int] = typer.Option(None, min=1, help="Local descriptors sampled to fit the "
                                                                    f"codebook (default {_FIT.max_descriptors})."),
    fit_iterations: Optional[int] = typer.Option(None, min=1, help="EM / k-means iterations at most when "
                                                 f"fitting (default {_FIT.iterations})."),
    svm: bool = typer.Option(False, "--svm", help="Also train one linear SVM per place on the reference "
                             "encodings (for localize/evaluate --mode svm; doubles the map's size)."),
    seed: int = typer.Option(0, help="Random seed for sampling and fitting."),
    save_codebook: Optional[str] = typer.Option(None, help="Also write the codebook to this .npz file."),
    storage: Optional[StorageOpt] = typer.Option(None, help=f"How the map stores reference encodings: int8 "
                                                 f"with a scale per row (default {DEFAULT_STORAGE}; a quarter of "
                                                 "float32's bytes, docs/results.md), float16 or float32. With "
                                                 "--append: the map's own unless given."),
    positions: Optional[list[str]] = typer.Option(None, metavar="FILE|exif", help="Where each reference is "
                                            "(with several drives: once per drive, in their order): a CSV "
                                            "with x,y (metres) or lat,lon (degrees), optional heading and z/alt, "
                                            "and a name column (or one row per reference, in order); a GPX "
                                            "track (.gpx) matched by time (--timestamps, or a bag's); or exif: "
                                            "the images' GPS tags (the geo extra). References without a fix "
                                            "are placed between fixes. Stored in the map; localize then answers "
                                            "with positions."),
    timestamps: Optional[list[Path]] = typer.Option(None, help="With --positions TRACK.gpx and a folder: a "
                                                    "CSV frame,stamp giving each reference's time (Unix "
                                                    "seconds), to match the track by time (once per drive)."),
    topic: Optional[str] = typer.Option(None, help="REFS is a ROS 1/2 bag or MCAP file: its image topic "
                                        "(sensor_msgs/Image or CompressedImage; the ros extra)."),
    positions_topic: Optional[str] = typer.Option(None, help="With a bag: the NavSatFix or Odometry topic "
                                                  "giving each image's position (interpolated in time)."),
    append: bool = typer.Option(False, "--append", help="Add each DRIVE as a drive of its own to the map at "
                                "--out, described and encoded as its own (its places copied, not re-encoded; "
                                "the map is replaced atomically); the map grows without refitting."),
    ray: Optional[str] = typer.Option(None, "--ray", metavar="ADDRESS", help="Describe and encode the "
                                      "references on a Ray cluster (the ray extra): local starts one on this "
                                      "machine, auto or HOST:PORT joins a running one; workers need the package "
                                      "and the same paths to the frames and the model. The same map as without."),
    index: Optional[str] = typer.Option(None, "--index", metavar="ivf|none", help="An index of the map's "
                                        "places that whole-route searches go through (index.ivf: a few ms at a "
                                        f"million places); default: ivf on maps of {IVF_MIN_REFS:,} places or "
                                        "more."),
    strict: bool = typer.Option(False, "--strict", help="Refuse a drive whose frames are not all one size "
                                "(default: a warning, and each frame is resized to the model's input)."),
    batch_size: int = typer.Option(8, min=1, help="Images per model run."),
    threads: int = typer.Option(0, min=0, help=THREADS_HELP),
) -> None:
    """Build a map from one or more drives of reference images: describe each image (a CNN tap by default, or
    a handcrafted front end), fit the codebook unless --codebook is given, encode every reference (an
    Improved Fisher Vector by default), optionally train an SVM per place, and write one map file that keeps
    each drive as a sequence of its own."""
    with user_errors():
        options = BuildOptions(features=_value(features), encoding=_value(encoding), model=model,
                               resize=_value(resize), codebook=codebook, components=components, pca_dim=pca_dim,
                               whiten=whiten, alpha=alpha, tfidf=tfidf, max_descriptors=max_descriptors,
                               fit_iterations=fit_iterations, svm=svm, seed=seed,
                               save_codebook=output_path(save_codebook) if save_codebook else None,
                               storage=_value(storage), positions=tuple(positions or ()),
                               timestamps=tuple(timestamps or ()), topic=topic,
                               positions_topic=positions_topic, append=append, batch_size=batch_size, threads=threads, ray=ray,
                               index=index, strict=strict,
                               inputs=GivenConventions(input_size, mean, std, bgr, _value(layout)))
        if index not in (None, "ivf", "none"):
            raise VprError(f"--index {index}: choose ivf or none")
        plan = plan_map(refs, output_path(out), options)
        with gather(plan) as inputs, typer.progressbar(length=len(inputs.files), label="extracting",
                                                       file=sys.stderr, hidden=not sys.stderr.isatty()) as bar:
            line = write_map(inputs, progress=bar.update)
        typer.echo(line, err=True)
