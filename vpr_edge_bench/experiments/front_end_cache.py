"""Cache every derived stream's similarity matrix against a map, per dataset and front end, for matcher experiments.

Beside each matrix it keeps what the streaming matcher reads, so that experiments run in seconds, encoding nothing.

    python -m vpr_edge_bench derive-streams --dataset ../shared/datasets/corridor --out out/corridor   # (and nordland-dev)
    python -m vpr_edge_bench front-end-cache --streams out/corridor out/nordland-dev --out out/fronts \\
        [--fronts ifv,ifv128,hog,sift,ldb,pixels,gem,random,noisy] [--threads 2]

For each dataset folder D (``derive-streams`` output) and front end F it builds OUT/D.name/F/map.npz
(kept if it exists) and writes, per stream kind K of ``streams.KINDS`` and for ``foreign`` (the
next dataset's ``aligned/`` frames, in ``--streams`` order, against this map: no frame is mapped),
OUT/D.name/F/K.npz (``np.savez``, no pickles; kept if it exists) with:

* ``sim`` (Q, R) float32: what ``evaluate`` scores, from the same library calls: the cosine similarities of
  ``sources.from_map`` (for ``pixels``: ``sources.from_pixels``' minus mean absolute difference);
* ``truth`` (Q, T) int64: the true references padded with -1 (``Truth.load``; foreign: all -1, T = 1);
* ``cue`` (Q,) float64: the ``stream`` matcher's motion cue of the query encodings (``Matcher.cue``);
* ``route`` (R,) bool and ``reach`` int: the map's standing references and likeness reach
  (``get_matcher("stream").on_route``);
* ``one_view`` (Q,) bool: ``truth.one_view`` with the map's ``run.map_same_view``;
* ``single_r1`` float: the ``single`` matcher's recall@1 at tolerance 0 (NaN for foreign);
* ``single_r1_tol`` float and ``tolerance`` int: the same at ``--tolerance`` (default 2: within +-2 frames of
  the CSV's reference; the derived CSVs name one reference a frame, so tolerance 0 is the exact frame).

``pixels`` files have no ``cue``, ``route``, ``reach`` or ``one_view`` (no map, no motion cue).

Front ends: ``ifv`` (the default build: D/map.npz copied), ``ifv128`` (``--components 128 --pca-dim 0``),
``hog`` and ``sift`` (HOG, dense SIFT: IFV encoding, the thesis's handcrafted front ends), ``ldb`` (LDB, a
binary descriptor of the whole image, no encoding), ``pixels`` (SeqSLAM's front end on D/ref, no map), ``gem``
(EfficientNet-Lite0 cut at stage5 + GeM, pretrained, exported by ``vpr_edge_export.onnx_export`` to
OUT/models/gem_160x120.onnx), ``random`` (the same network with seeded random weights, Kaiming-normal
fan-in convolutions: a state dict written to OUT/models/ and exported by the same exporter with
``--weights``), ``noisy`` (``ifv``'s query and reference encodings with seeded Gaussian noise, its standard
deviation bisected so that ``single``'s aligned-stream R@1 at ``--tolerance`` is about ``--noisy-target``,
or ``--noisy-fraction`` of ``ifv``'s own where that is lower; the noisy references and the deviation are
kept in OUT/D.name/noisy/noise.npz). A front end that fails to build is reported in one line and skipped.
At the end: tables of ``single``'s aligned-stream R@1 per dataset and front end.
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import time
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vpr_edge.errors import VprError
from vpr_edge.evaluation import sources
from vpr_edge.evaluation.run import check_truth_fits, map_same_view
from vpr_edge.evaluation.scoring import evaluate_mode
from vpr_edge.evaluation.truth import Truth, one_view
from vpr_edge.frames.frame import Frame
from vpr_edge.frames.images import list_images
from vpr_edge.map import MapQuery
from vpr_edge.map.make import BuildOptions, plan_map, write_map
from vpr_edge.matchers import get_matcher
from vpr_edge.threads import use_threads
from vpr_edge_bench.folder import StreamsFolder, streams_folders
from vpr_edge_bench.runner import parser, run_checked

FRONTS: tuple[str, ...] = ("ifv", "ifv128", "hog", "sift", "ldb", "pixels", "gem", "random", "noisy")
FOREIGN = "foreign"
MODEL_SIZE = (160, 120)          # the global models' input, width x height
BACKBONE, TAP = "efficientnet_lite0", "stage5"


class FrontEndFailed(Exception):
    """A front end that could not be built (its one-line reason)."""


@dataclass(frozen=True)
class Stream:
    """One query stream: its ``name`` (a stream kind, or ``foreign``), its frame folder and its ground-truth
    CSV (None: foreign, no frame shows a mapped place)."""

    name: str
    frames: Path
    gt: Path | None

    def truth_name(self) -> str:
        return str(self.gt) if self.gt is not None else f"{self.frames} (foreign: unmapped)"


@dataclass
class Encoded:
    """A stream as a front end sees it: the query encodings (Q, D) of its decoded frames (None: pixels), their
    (Q, R) similarities to the references, and their padded truth rows."""

    encodings: np.ndarray | None
    sim: np.ndarray
    truth: np.ndarray


def streams_of(folder: StreamsFolder, other: StreamsFolder | None) -> list[Stream]:
    """Every derived stream of ``folder``, then the foreign one (``other``'s aligned frames) if given."""
    out = [Stream(k, folder.frames(k), folder.truth(k)) for k in folder.kinds]
    if other is not None:
        out.append(Stream(FOREIGN, other.frames("aligned"), None))
    return out


def save_npz(path: Path, arrays: dict[str, np.ndarray | float | int]) -> None:
    """``np.savez`` written atomically (a run stopped midway leaves no file that a rerun would keep)."""
    tmp = path.with_name(f".{path.stem}.tmp.npz")
    np.savez(tmp, **{k: np.asarray(v) for k, v in arrays.items()})
    os.replace(tmp, path)


# --- the maps -----------------------------------------------------------------------------------------------

def build_with(refs: Path, out: Path, options: BuildOptions) -> None:
    """``build-map`` with ``options`` on ``refs`` into ``out`` (the library's plan + write)."""
    print(write_map(plan_map(refs, out, options)), flush=True)


def run_exporter(args: list[str], out: Path) -> None:
    """``python -m vpr_edge_export.onnx_export ARGS --out OUT``; FrontEndFailed with its last error line if it
    fails."""
    out.parent.mkdir(parents=True, exist_ok=True)
    args = [*args, "--out", str(out)]
    proc = subprocess.run([sys.executable, "-m", "vpr_edge_export.onnx_export", *args], capture_output=True,
                          text=True)
    if proc.returncode:
        lines = [ln for ln in (proc.stderr or proc.stdout).splitlines() if ln.strip()]
        raise FrontEndFailed(f"onnx_export exited {proc.returncode}: {lines[-1] if lines else 'no message'}")


def export_gem(models: Path) -> Path:
    """The pretrained EfficientNet-Lite0/stage5 + GeM ONNX (exported once into ``models``)."""
    out = models / f"gem_{MODEL_SIZE[0]}x{MODEL_SIZE[1]}.onnx"
    if not out.is_file():
        run_exporter(["--architecture", "gem", "--backbone", BACKBONE, "--tap", TAP, "--width", str(MODEL_SIZE[0]),
                      "--height", str(MODEL_SIZE[1])], out)
    return out


def random_weights(path: Path, seed: int) -> None:
    """A state dict of the backbone cut at TAP with seeded random weights, saved to ``path``. Convolutions are
    Kaiming-normal over their fan-in (PyTorch's default init shrinks the activations ~1e6-fold by stage5, and
    GeM's clamp then makes every descriptor alike); batch norms are left at identity statistics."""
    import torch
    from torch import nn

    from vpr_edge_export.backbones import BACKBONES

    torch.manual_seed(seed)
    net = BACKBONES[BACKBONE].build(TAP)
    for module in net.modules():
        if isinstance(module, nn.Conv2d):
            nn.init.kaiming_normal_(module.weight, mode="fan_in", nonlinearity="relu")
            if module.bias is not None:
                nn.init.zeros_(module.bias)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    torch.save(net.state_dict(), tmp)
    os.replace(tmp, path)


def export_random(models: Path, seed: int) -> Path:
    """The random-weight counterpart of ``export_gem``: the same network and exporter, ``--weights`` random."""
    out = models / f"random_seed{seed}_{MODEL_SIZE[0]}x{MODEL_SIZE[1]}.onnx"
    if not out.is_file():
        weights = models / f"{BACKBONE}_{TAP}_random_seed{seed}.pt"
        if not weights.is_file():
            random_weights(weights, seed)
        run_exporter(["--architecture", "gem", "--backbone", BACKBONE, "--tap", TAP, "--weights", str(weights),
                      "--width", str(MODEL_SIZE[0]), "--height", str(MODEL_SIZE[1])], out)
    return out


def ensure_map(front: str, folder: StreamsFolder, out: Path, models: Path, threads: int, seed: int
               ) -> Path | None:
    """OUT/D/F/map.npz of front end ``front`` for dataset ``folder`` (built unless it exists); None for a
    front end without a map of its own (pixels; noisy reads ifv's)."""
    if front in ("pixels", "noisy"):
        return None
    path = out / "map.npz"
    if path.is_file():
        return path
    out.mkdir(parents=True, exist_ok=True)
    refs = folder.ref
    t0 = time.perf_counter()
    if front == "ifv":
        tmp = path.with_name(".map.tmp.npz")
        shutil.copyfile(folder.map, tmp)
        os.replace(tmp, path)
    elif front == "ifv128":
        build_with(refs, path, BuildOptions(components=128, pca_dim=0, threads=threads))
    elif front in ("hog", "sift"):
        build_with(refs, path, BuildOptions(features=front, encoding="ifv", threads=threads))
    elif front == "ldb":
        build_with(refs, path, BuildOptions(features="ldb", encoding="none", threads=threads))
    elif front == "gem":
        build_with(refs, path, BuildOptions(model=export_gem(models), threads=threads))
    elif front == "random":
        build_with(refs, path, BuildOptions(model=export_random(models, seed), threads=threads))
    else:
        raise ValueError(f"unknown front end {front!r}")
    print(f"{path}: built in {time.perf_counter() - t0:.1f} s", flush=True)
    return path


# --- one stream ---------------------------------------------------------------------------------------------

def frame_count(stream: Stream) -> int:
    return len(list_images(stream.frames))


def load_truth(stream: Stream, query: MapQuery | None) -> np.ndarray:
    """The stream's padded truth as ``evaluate`` reads it (with the map's positions and labels), or all -1."""
    if stream.gt is None:
        return np.full((frame_count(stream), 1), -1, np.int64)
    rows, _ = Truth(gt=stream.gt).load(None if query is None else query.map.positions,
                                       None if query is None else query.map.labels)
    return rows


def skip_warning(frame: Frame) -> None:
    print(f"warning: skipped frame {frame.name} (not decodable)", file=sys.stderr)


def kept_rows(sims: sources.Similarities, truth: np.ndarray, stream: Stream) -> np.ndarray:
    """``truth``'s rows of the frames that decoded, checked against the matrix as ``evaluate`` does."""
    rows = truth if sims.kept is None else truth[sims.kept]
    check_truth_fits(rows, None, sims.cosine, stream.truth_name())
    return rows


def encode_map(query: MapQuery, stream: Stream) -> Encoded:
    """``stream`` through ``query``'s chain (``sources.from_map``, as ``evaluate``)."""
    truth = load_truth(stream, query)
    sims = sources.from_map(query, stream.frames, len(truth), stream.truth_name(), skip_warning)
    return Encoded(sims.encodings, sims.cosine, kept_rows(sims, truth, stream))


def encode_pixels(refs: Path, stream: Stream) -> Encoded:
    """``stream`` against ``refs`` by SeqSLAM's pixel front end (``sources.from_pixels``, as ``evaluate``)."""
    truth = load_truth(stream, None)
    sims = sources.from_pixels(refs, stream.frames, len(truth), stream.truth_name(), skip_warning)
    return Encoded(None, sims.cosine, kept_rows(sims, truth, stream))


def single_r1(sim: np.ndarray, truth: np.ndarray, tolerance: int = 0) -> float:
    """The ``single`` matcher's recall@1 within ``tolerance`` references (NaN when no frame is mapped)."""
    if not (truth >= 0).any():
        return float("nan")
    return float(evaluate_mode(get_matcher("single"), sim, truth, tolerance=tolerance).recall[1])


def unit(x: np.ndarray) -> np.ndarray:
    """Rows scaled to unit length (zero rows left zero), float32."""
    x = np.asarray(x, np.float32)
    n = np.linalg.norm(x, axis=1, keepdims=True)
    return np.divide(x, n, out=np.zeros_like(x), where=n > 0)


def record(enc: Encoded, references: list[np.ndarray] | None, tolerance: int
           ) -> dict[str, np.ndarray | float | int]:
    """What a stream's file holds: the matrix and truth, the single matcher's R@1 (at tolerance 0 and at
    ``tolerance``), and with ``references`` (the map's encodings in route order, as blocks) the motion cue,
    route, reach and one-view frames."""
    out: dict[str, np.ndarray | float | int] = {
        "sim": enc.sim.astype(np.float32), "truth": enc.truth, "single_r1": single_r1(enc.sim, enc.truth),
        "single_r1_tol": single_r1(enc.sim, enc.truth, tolerance), "tolerance": tolerance}
    if references is not None and enc.encodings is not None:
        stream = get_matcher("stream")
        on = stream.on_route(iter(references), None)
        out["cue"] = stream.cue(enc.encodings)
        if on.route is not None:
            out["route"] = np.asarray(on.route, bool)
        out["reach"] = int(on.reach)
        out["one_view"] = one_view(enc.truth, map_same_view(iter(references)))
    return out


# --- noisy ----------------------------------------------------------------------------------------------------

def noise_rng(seed: int, name: str) -> np.random.Generator:
    """A generator seeded by ``seed`` and a name (the references, or a stream): reproducible per stream."""
    return np.random.default_rng([seed, zlib.crc32(name.encode())])


def noisy(x: np.ndarray, std: float, z: np.ndarray) -> np.ndarray:
    """Unit rows of ``x`` plus ``std`` times the standard normal draws ``z``, back to unit length."""
    return unit(unit(x) + std * z)


@dataclass
class Noise:
    """``ifv``'s encodings with Gaussian noise: the deviation ``std`` (per dimension, on unit encodings),
    the noisy references (R, D) and the seed of the query draws."""

    std: float
    references: np.ndarray
    seed: int

    def apply(self, enc: Encoded, name: str) -> Encoded:
        """The stream ``enc`` (``ifv``'s) with noisy queries, its cosines to the noisy references."""
        z = noise_rng(self.seed, name).standard_normal(enc.encodings.shape).astype(np.float32)
        q = noisy(enc.encodings, self.std, z)
        return Encoded(q, (q @ self.references.T).astype(np.float64), enc.truth)


def calibrate_noise(refs: np.ndarray, aligned: Encoded, seed: int, target: float, fraction: float,
                    tolerance: int, steps: int = 30) -> tuple[float, float, float]:
    """(deviation, R@1 without noise, R@1 aimed at): the per-dimension deviation (bisected on a log scale,
    draws fixed) at which ``single``'s R@1 within ``tolerance`` on the aligned stream is closest to ``target``,
    or to ``fraction`` of the R@1 without noise where that is lower (noise cannot raise it)."""
    zr = noise_rng(seed, "references").standard_normal(refs.shape).astype(np.float32)
    zq = noise_rng(seed, "aligned").standard_normal(aligned.encodings.shape).astype(np.float32)

    def r1(std: float) -> float:
        sim = (noisy(aligned.encodings, std, zq) @ noisy(refs, std, zr).T).astype(np.float64)
        return single_r1(sim, aligned.truth, tolerance)

    clean = r1(0.0)
    target = min(target, fraction * clean)
    lo, hi = 1e-4, 1.0   # per dimension, on unit vectors of D dims: noise length std * sqrt(D)
    best = (abs(r1(hi) - target), hi)
    for _ in range(steps):
        mid = float(np.sqrt(lo * hi))
        got = r1(mid)
        best = min(best, (abs(got - target), mid))
        if abs(got - target) < 0.01:
            break
        lo, hi = (mid, hi) if got > target else (lo, mid)
    return best[1], clean, target


def ensure_noise(path: Path, refs: np.ndarray, aligned: Callable[[], Encoded], seed: int, target: float,
                 fraction: float, tolerance: int) -> Noise:
    """The noisy references and deviation kept in ``path`` (noise.npz), calibrated and written if absent."""
    if path.is_file():
        with np.load(path, allow_pickle=False) as f:
            return Noise(float(f["std"]), f["references"], int(f["seed"]))
    std, clean, target = calibrate_noise(refs, aligned(), seed, target, fraction, tolerance)
    zr = noise_rng(seed, "references").standard_normal(refs.shape).astype(np.float32)
    noise = Noise(std, noisy(refs, std, zr), seed)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_npz(path, {"std": std, "references": noise.references, "seed": seed, "target_r1": target,
                    "clean_r1": clean, "tolerance": tolerance})
    print(f"{path}: noise std {std:.4g} a dimension (length {std * np.sqrt(refs.shape[1]):.3g} on unit "
          f"encodings of {refs.shape[1]} dims), aiming at single R@1 {target:.3f} within {tolerance} (ifv's "
          f"own {clean:.3f})", flush=True)
    return noise


# --- the run --------------------------------------------------------------------------------------------------

def stream_line(path: Path, arrays: dict, seconds: float, kept: bool = False) -> str:
    q, r = np.shape(arrays["sim"])
    return (f"{path}: sim {q}x{r}, single R@1 {float(arrays['single_r1']):.3f} (within "
            f"{int(arrays['tolerance'])}: {float(arrays['single_r1_tol']):.3f}), "
            + ("exists" if kept else f"{seconds:.1f} s"))


def read_r1(path: Path, key: str) -> float | None:
    if not path.is_file():
        return None
    with np.load(path, allow_pickle=False) as f:
        return float(f[key])


class DatasetRun:
    """One dataset's front ends; ``ifv``'s map and encodings opened once and shared with ``noisy``."""

    def __init__(self, folder: StreamsFolder, other: StreamsFolder | None, out: Path, models: Path, threads: int,
                 seed: int, noisy: tuple[float, float], tolerance: int) -> None:
        self.folder, self.out, self.models = folder, out / folder.name, models
        self.threads, self.seed, self.noisy, self.tolerance = threads, seed, noisy, tolerance
        self.streams = streams_of(folder, other)
        self._ifv: dict[str, Encoded] = {}
        self._ifv_query: MapQuery | None = None

    def ifv_query(self) -> MapQuery:
        if self._ifv_query is None:
            path = ensure_map("ifv", self.folder, self.out / "ifv", self.models, self.threads, self.seed)
            self._ifv_query = MapQuery(path, None, self.threads)
        return self._ifv_query

    def ifv_encoded(self, stream: Stream) -> Encoded:
        if stream.name not in self._ifv:
            self._ifv[stream.name] = encode_map(self.ifv_query(), stream)
        return self._ifv[stream.name]

    def front(self, front: str) -> None:
        """Every stream's file of ``front`` (each kept if it exists); FrontEndFailed if its map cannot be built."""
        folder = self.out / front
        folder.mkdir(parents=True, exist_ok=True)
        todo = [s for s in self.streams if not (folder / f"{s.name}.npz").is_file()]
        for s in self.streams:
            if s not in todo:
                with np.load(folder / f"{s.name}.npz", allow_pickle=False) as f:
                    print(stream_line(folder / f"{s.name}.npz", dict(f), 0.0, kept=True), flush=True)
        if not todo:
            return
        try:
            map_path = ensure_map(front, self.folder, folder, self.models, self.threads, self.seed)
            query = None if front in ("pixels", "noisy") else \
                self.ifv_query() if front == "ifv" else MapQuery(map_path, None, self.threads)
            noise = None
            if front == "noisy":
                refs = unit(np.concatenate([b.astype(np.float32) for b in self.ifv_query().references()]))
                aligned = next(s for s in self.streams if s.name == "aligned")
                noise = ensure_noise(folder / "noise.npz", refs, lambda: self.ifv_encoded(aligned), self.seed,
                                     *self.noisy, self.tolerance)
        except FrontEndFailed:
            raise
        except Exception as e:   # noqa: BLE001 (one front end's failure must not stop the others)
            raise FrontEndFailed(f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}") from e
        for s in todo:
            path = folder / f"{s.name}.npz"
            t0 = time.perf_counter()
            try:
                if front == "pixels":
                    arrays = record(encode_pixels(self.folder.ref, s), None, self.tolerance)
                elif front == "noisy":
                    arrays = record(noise.apply(self.ifv_encoded(s), s.name), [noise.references], self.tolerance)
                else:
                    enc = self.ifv_encoded(s) if front == "ifv" else encode_map(query, s)
                    arrays = record(enc, list(query.references()), self.tolerance)
            except Exception as e:   # noqa: BLE001 (one stream's failure must not stop the others)
                print(f"{path}: failed: {type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}",
                      flush=True)
                continue
            save_npz(path, arrays)
            print(stream_line(path, arrays, time.perf_counter() - t0), flush=True)


def table(out: Path, datasets: list[StreamsFolder], fronts: list[str], key: str) -> str:
    """Markdown: single's R@1 (``key`` of the files) on the aligned stream, dataset by front end ("-": no
    file)."""
    lines = ["| dataset | " + " | ".join(fronts) + " |", "|---|" + "---|" * len(fronts)]
    for d in datasets:
        cells = []
        for f in fronts:
            r = read_r1(out / d.name / f / "aligned.npz", key)
            cells.append("-" if r is None else f"{r:.3f}")
        lines.append(f"| {d.name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def parse_fronts(text: str) -> list[str]:
    names = [n.strip() for n in text.split(",") if n.strip()]
    unknown = [n for n in names if n not in FRONTS]
    if unknown or not names:
        raise VprError(f"--fronts {text}: unknown front end(s) {', '.join(unknown) or '(none)'}; choose from "
                       f"{', '.join(FRONTS)}")
    return names


def run(a: argparse.Namespace) -> int:
    t0 = time.perf_counter()
    fronts = parse_fronts(a.fronts)
    datasets = streams_folders(a.streams, map=False, ref=True, distinct=True)   # their names name OUT's subfolders
    threads = use_threads(a.threads)
    models = a.out / "models"
    failed: list[str] = []
    for i, folder in enumerate(datasets):
        other = datasets[(i + 1) % len(datasets)] if len(datasets) > 1 else None
        ds = DatasetRun(folder, other, a.out, models, threads, a.seed, (a.noisy_target, a.noisy_fraction),
                        a.tolerance)
        for front in fronts:
            try:
                ds.front(front)
            except FrontEndFailed as e:
                line = f"{folder.name}/{front}: not built: {e}"
                print(line, flush=True)
                failed.append(line)
    for title, key in (("tolerance 0", "single_r1"), (f"within {a.tolerance}", "single_r1_tol")):
        print(f"\nsingle R@1 ({title}) on the aligned stream\n\n{table(a.out, datasets, fronts, key)}")
    if failed:
        print("\nfailed:\n" + "\n".join(failed))
    print(f"\ntotal {time.perf_counter() - t0:.0f} s")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    p = parser(__name__, __doc__)
    p.add_argument("--streams", type=Path, nargs="+", required=True, help="derived-streams folders")
    p.add_argument("--out", type=Path, required=True, help="cache folder: OUT/DATASET/FRONT/STREAM.npz")
    p.add_argument("--fronts", default=",".join(FRONTS), help=f"comma-separated, of {', '.join(FRONTS)}")
    p.add_argument("--threads", type=int, default=2, help="NumPy's and onnxruntime's threads (0 = one a core)")
    p.add_argument("--seed", type=int, default=0, help="seed of the random weights and of the noise")
    p.add_argument("--tolerance", type=int, default=2,
                   help="the second R@1 figure's tolerance (references either side), and the noisy calibration's")
    p.add_argument("--noisy-target", type=float, default=0.4,
                   help="single's aligned-stream R@1 (at --tolerance) the noisy front end's deviation is bisected to")
    p.add_argument("--noisy-fraction", type=float, default=0.6,
                   help="... or this fraction of ifv's own R@1, where that is lower")
    return run_checked(__name__, lambda: run(p.parse_args(argv)))

