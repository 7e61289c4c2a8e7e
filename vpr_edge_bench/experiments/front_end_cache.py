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
At the end: tables of ``single``'s aligned-stream R@1 per dataset and front end. ``--standardise`` keeps
the standardised cosines instead (``vpr-edge evaluate --standardise``; ``pixels`` keeps its own), into another
OUT: copy a plain cache's map.npz and noise.npz files and models/ there first, and nothing is rebuilt.
"""
from __future__ import annotations

import argparse
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vpr_edge.errors import VprError
from vpr_edge.map import MapQuery
from vpr_edge.threads import use_threads
from vpr_edge_bench.folder import StreamsFolder, streams_folders
from vpr_edge_bench.front_end_maps import FRONTS, FrontEndFailed, ensure_map
from vpr_edge_bench.front_end_streams import (Encoded, Stream, encode_map, encode_pixels, ensure_noise, record,
                                              save_npz, streams_of, unit)
from vpr_edge_bench.runner import parser, run_checked


def stream_line(path: Path, arrays: dict, seconds: float, kept: bool = False) -> str:
    """One stream file's line: its matrix's shape, single's R@1 (at 0 and at its tolerance), and the seconds
    taken or "exists"."""
    q, r = np.shape(arrays["sim"])
    return (f"{path}: sim {q}x{r}, single R@1 {float(arrays['single_r1']):.3f} (within "
            f"{int(arrays['tolerance'])}: {float(arrays['single_r1_tol']):.3f}), "
            + ("exists" if kept else f"{seconds:.1f} s"))


def read_r1(path: Path, key: str) -> float | None:
    """The R@1 ``key`` of a stream file, None when there is no file."""
    if not path.is_file():
        return None
    with np.load(path, allow_pickle=False) as f:
        return float(f[key])


class DatasetRun:
    """One dataset's front ends; ``ifv``'s map and encodings opened once and shared with ``noisy``."""

    def __init__(self, folder: StreamsFolder, other: StreamsFolder | None, out: Path, models: Path, threads: int,
                 seed: int, noisy: tuple[float, float], tolerance: int, standardise: bool = False) -> None:
        """``folder``'s streams (and ``other``'s aligned frames as foreign) into OUT/folder.name; ``noisy`` is
        (--noisy-target, --noisy-fraction); ``standardise``: keep the standardised cosines (``--standardise``)."""
        self.folder, self.out, self.models = folder, out / folder.name, models
        self.threads, self.seed, self.noisy, self.tolerance = threads, seed, noisy, tolerance
        self.standardise = standardise
        self.streams = streams_of(folder, other)
        self._ifv: dict[str, Encoded] = {}
        self._ifv_query: MapQuery | None = None

    def ifv_query(self) -> MapQuery:
        """``ifv``'s map (built or copied unless it exists), opened once."""
        if self._ifv_query is None:
            path = ensure_map("ifv", self.folder, self.out / "ifv", self.models, self.threads, self.seed)
            self._ifv_query = MapQuery(path, None, self.threads)
        return self._ifv_query

    def ifv_encoded(self, stream: Stream) -> Encoded:
        """``stream`` through ``ifv``'s map, encoded once (``ifv`` and ``noisy`` share it)."""
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
                    arrays = record(noise.apply(self.ifv_encoded(s), s.name), [noise.references], self.tolerance,
                                    self.standardise)
                else:
                    enc = self.ifv_encoded(s) if front == "ifv" else encode_map(query, s)
                    arrays = record(enc, list(query.references()), self.tolerance, self.standardise)
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
    """``--fronts``' comma-separated names, checked against FRONTS (VprError: unknown or none)."""
    names = [n.strip() for n in text.split(",") if n.strip()]
    unknown = [n for n in names if n not in FRONTS]
    if unknown or not names:
        raise VprError(f"--fronts {text}: unknown front end(s) {', '.join(unknown) or '(none)'}; choose from "
                       f"{', '.join(FRONTS)}")
    return names


def run(a: argparse.Namespace) -> int:
    """Every dataset's front ends (a failed one reported and skipped), then the R@1 tables; exit code 0."""
    t0 = time.perf_counter()
    fronts = parse_fronts(a.fronts)
    datasets = streams_folders(a.streams, map=False, ref=True, distinct=True)   # their names name OUT's subfolders
    threads = use_threads(a.threads)
    models = a.out / "models"
    failed: list[str] = []
    for i, folder in enumerate(datasets):
        other = datasets[(i + 1) % len(datasets)] if len(datasets) > 1 else None
        ds = DatasetRun(folder, other, a.out, models, threads, a.seed, (a.noisy_target, a.noisy_fraction),
                        a.tolerance, a.standardise)
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
    """``python -m vpr_edge_bench front-end-cache [OPTIONS]``: parse the options and ``run``."""
    p = parser(__name__, __doc__)
    p.add_argument("--streams", type=Path, nargs="+", required=True, help="derived-streams folders")
    p.add_argument("--out", type=Path, required=True, help="cache folder: OUT/DATASET/FRONT/STREAM.npz")
    p.add_argument("--fronts", default=",".join(FRONTS), help=f"comma-separated, of {', '.join(FRONTS)}")
    p.add_argument("--standardise", action="store_true",
                   help="keep the standardised cosines (evaluate --standardise; pixels keep their own): into "
                        "another --out, whose maps may be copied from a plain cache's")
    p.add_argument("--threads", type=int, default=2, help="NumPy's and onnxruntime's threads (0 = one a core)")
    p.add_argument("--seed", type=int, default=0, help="seed of the random weights and of the noise")
    p.add_argument("--tolerance", type=int, default=2,
                   help="the second R@1 figure's tolerance (references either side), and the noisy calibration's")
    p.add_argument("--noisy-target", type=float, default=0.4,
                   help="single's aligned-stream R@1 (at --tolerance) the noisy front end's deviation is bisected to")
    p.add_argument("--noisy-fraction", type=float, default=0.6,
                   help="... or this fraction of ifv's own R@1, where that is lower")
    return run_checked(__name__, lambda: run(p.parse_args(argv)))

