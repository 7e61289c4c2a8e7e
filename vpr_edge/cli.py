"""Command line: ``vpr-edge build-map`` and ``vpr-edge localize``."""
from __future__ import annotations

import contextlib
import csv
import json
import sys
from collections.abc import Iterator
from enum import Enum
from pathlib import Path
from typing import IO, Optional

import typer

from vpr_edge.codebook import Codebook
from vpr_edge.errors import VprError
from vpr_edge.extract import FeatureExtractor, default_model_path
from vpr_edge.images import Frame, list_images, open_stream
from vpr_edge.localize import Match, localize
from vpr_edge.mapfile import PlaceMap, build_map

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  help="Visual place recognition on a CPU: build a map of reference images, then localise "
                       "a stream of frames against it (ONNX features, Improved Fisher Vectors, DTW).")


class ModeOpt(str, Enum):
    stream = "stream"
    dtw = "dtw"
    single = "single"


class VariantOpt(str, Enum):
    similarity = "similarity"
    distance = "distance"


class FormatOpt(str, Enum):
    csv = "csv"
    jsonl = "jsonl"


@contextlib.contextmanager
def _user_errors() -> Iterator[None]:
    """Turn VprError into one line on stderr and exit code 2; Ctrl-C into exit code 130."""
    try:
        yield
    except VprError as e:
        typer.echo(f"vpr-edge: error: {e}", err=True)
        raise typer.Exit(2) from None
    except KeyboardInterrupt:
        typer.echo("vpr-edge: interrupted", err=True)
        raise typer.Exit(130) from None


_MODEL_HELP = "ONNX feature model exported by vpr_edge_export (default: the bundled EfficientNet-Lite0 tap)."
_THREADS_HELP = "onnxruntime intra-op threads (0 = one per core)."


@app.command("build-map")
def build_map_cmd(
    refs: Path = typer.Argument(..., help="Folder of reference images, taken in file-name order."),
    out: Path = typer.Option(..., "--out", "-o", help="Map file to write (.npz); written atomically."),
    model: Optional[Path] = typer.Option(None, help=_MODEL_HELP),
    codebook: Optional[Path] = typer.Option(
        None, help="Reuse this codebook (.npz from --save-codebook) instead of fitting one on the references."),
    components: int = typer.Option(128, min=1, help="GMM components M when fitting (thesis: 128)."),
    pca_dim: Optional[int] = typer.Option(None, min=1, help="Reduce descriptors to this many dims by PCA "
                                                            "before the GMM (default: no PCA)."),
    whiten: bool = typer.Option(True, help="Whiten the PCA output (with --pca-dim)."),
    alpha: float = typer.Option(0.5, min=0.0, max=1.0, help="Signed power normalisation exponent (1 = off)."),
    max_descriptors: int = typer.Option(100_000, min=1, help="Local descriptors sampled to fit the codebook."),
    seed: int = typer.Option(0, help="Random seed for sampling and GMM initialisation."),
    save_codebook: Optional[Path] = typer.Option(None, help="Also write the codebook to this .npz file."),
    batch_size: int = typer.Option(8, min=1, help="Images per model run."),
    threads: int = typer.Option(0, min=0, help=_THREADS_HELP),
) -> None:
    """Build a map from a folder of reference images: extract features, fit the codebook (PCA + GMM) unless
    --codebook is given, encode every reference as an Improved Fisher Vector, and write one map file."""
    with _user_errors():
        extractor = FeatureExtractor(model or default_model_path(), threads)
        given = None
        if codebook:
            given, cb_meta = Codebook.load(codebook)
            if cb_meta.get("model_sha256") not in (None, extractor.fingerprint):
                raise VprError(f"{codebook}: codebook was fitted on features of another model "
                               f"(sha256 {cb_meta['model_sha256'][:12]}, this is {extractor.fingerprint[:12]})")
        files = list_images(refs)
        with typer.progressbar(length=len(files), label="extracting", file=sys.stderr) as bar:
            place_map = build_map(files, extractor, given, components, pca_dim, whiten, alpha, max_descriptors,
                                  batch_size, seed, progress=bar.update)
        place_map.save(out)
        if save_codebook:
            place_map.codebook.save(save_codebook, {"model_sha256": extractor.fingerprint})
        typer.echo(f"wrote {out}: {len(place_map.names)} references, {place_map.encodings.shape[1]}-dim "
                   f"encodings, {place_map.codebook.gmm.n_components}-component codebook "
                   f"({'fitted on the references' if given is None else 'given'})", err=True)


def _writer(fmt: str, stream: IO[str]):
    if fmt == "csv":
        w = csv.writer(stream, lineterminator="\n")
        w.writerow(["frame_index", "frame", "ref_index", "ref", "score"])
        return lambda m: w.writerow([m.frame_index, m.frame, m.ref_index, m.ref, f"{m.score:.6f}"])
    return lambda m: stream.write(json.dumps(m.__dict__ | {"score": round(m.score, 6)}) + "\n")


@app.command("localize")
def localize_cmd(
    map_path: Path = typer.Option(..., "--map", "-m", help="Map file written by build-map."),
    stream: Path = typer.Option(..., "--stream", "-s", help="Folder of frames (file-name order) or a video file."),
    model: Optional[Path] = typer.Option(None, help="ONNX feature model; must be the map's model (default: the "
                                  "model file the map was built with if it still exists, else the bundled one)."),
    mode: ModeOpt = typer.Option(ModeOpt.stream, help="stream: streaming DTW, a result per frame as it "
                                 "arrives, bounded memory; dtw: offline DTW over the whole sequence (thesis); "
                                 "single: best single match per frame, no sequence information."),
    variant: VariantOpt = typer.Option(VariantOpt.similarity, help="Offline DTW form: similarity (maximise "
                                       "summed cosine, thesis) or distance (minimise summed 1 - cosine)."),
    open_ends: bool = typer.Option(False, "--open-ends", help="Offline DTW only: let the path start and end "
                                   "at any reference (the query covers part of the mapped route)."),
    decay: float = typer.Option(0.9, min=0.01, max=0.999, help="Streaming DTW memory: each frame discounts "
                                "the past by this factor (about 1/(1-decay) frames remembered)."),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="Write results here instead of stdout."),
    fmt: Optional[FormatOpt] = typer.Option(None, "--format", help="csv or jsonl (default: from --out's "
                                            "suffix, csv on stdout)."),
    batch_size: int = typer.Option(1, min=1, help="Frames per model run (1 = lowest latency)."),
    threads: int = typer.Option(0, min=0, help=_THREADS_HELP),
) -> None:
    """Localise every frame of a stream against a map. One line per frame: frame index, frame name,
    matched reference index and name, score (higher = more confident). Undecodable frames are reported on
    stderr and skipped."""
    with _user_errors():
        place_map = PlaceMap.load(map_path)
        extractor = FeatureExtractor(place_map.model_path(model), threads)
        place_map.check_model(extractor, map_path)
        frames, count = open_stream(stream)
        chosen = fmt.value if fmt else ("jsonl" if out and out.suffix in (".jsonl", ".json") else "csv")
        skipped = 0

        def skip(frame: Frame) -> None:
            nonlocal skipped
            skipped += 1
            typer.echo(f"\nvpr-edge: warning: {frame.error}; frame skipped", err=True)

        sink = open(out, "w", newline="") if out else sys.stdout
        try:
            write = _writer(chosen, sink)
            written = 0
            with typer.progressbar(length=count or 0, label="localizing", file=sys.stderr,
                                   hidden=count is None) as bar:
                for match in localize(frames, place_map, extractor, mode.value, variant.value, decay,
                                      batch_size, open_ends, skip):
                    write(match)
                    sink.flush()  # a line per frame, as it happens
                    written += 1
                    bar.update(1)
        finally:
            if out:
                sink.close()
        if written == 0:
            raise VprError(f"{stream}: none of its frames could be decoded")
        if skipped:
            typer.echo(f"vpr-edge: {skipped} undecodable frame(s) skipped", err=True)


@app.command("info")
def info_cmd(map_path: Path = typer.Argument(..., help="Map file written by build-map.")) -> None:
    """Describe a map: references, encoding size, codebook, model and settings (JSON on stdout)."""
    with _user_errors():
        pm = PlaceMap.load(map_path)
        meta = {k: v for k, v in pm.meta.items() if k not in ("names", "n_refs", "dim")}  # said once, below
        summary = {"references": len(pm.names), "first": pm.names[0], "last": pm.names[-1],
                   "encoding_dims": int(pm.encodings.shape[1]), "size_mb": round(map_path.stat().st_size / 1e6, 2)}
        typer.echo(json.dumps(summary | meta, indent=1, sort_keys=True))


def main() -> None:
    """Console-script entry point."""
    app()


if __name__ == "__main__":
    main()
