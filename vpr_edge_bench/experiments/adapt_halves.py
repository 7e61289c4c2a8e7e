"""A map adapted on one half of its route, scored on the other: vpr-edge adapt against the label-free figures.

    python -m vpr_edge_bench adapt-halves --streams out/nordland-dev --work out/adapt/nordland-dev

The derived-streams folder's aligned stream (STREAMS/aligned, frame i at place i) is cut where the map's
references are (``route_halves.half_bounds``). Its first-half frames, labelled by a CSV, are the drive
``vpr-edge adapt`` learns from (WORK/learn/, links to the frames, and WORK/learn.csv); the adapted map is
WORK/adapted.npz. Both maps are then cut to their second-half places (WORK/test.plain.npz,
WORK/test.adapted.npz) and scored on the second-half frames (WORK/test/, WORK/test.csv) by ``evaluate``:
no place and no image is shared with what was learned. The codebook is the map's own (fitted on every
reference, without labels). Printed per tolerance: single-frame R@1 and ``stream``'s mapped frames answered
right, raw and ``--standardise``d cosines, plain and adapted maps, with the commands run.
"""
from __future__ import annotations

import argparse
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vpr_edge.errors import VprError
from vpr_edge.encoders.adapt import MIN_PAIRS
from vpr_edge.evaluation import Source, Truth, evaluate
from vpr_edge.evaluation.truth import write_ground_truth
from vpr_edge.frames.images import list_images
from vpr_edge.map.adapt import LabelledDrive, adapt_map
from vpr_edge.map.drives import Drives
from vpr_edge.map.io import load_map, save_map
from vpr_edge.map.model import PlaceMap
from vpr_edge.matchers import get_matcher
from vpr_edge.threads import use_threads
from vpr_edge_bench.route_halves import half_bounds, other_half
from vpr_edge_bench.runner import parser, run_checked

TOLERANCES = (0, 1, 2)


def cut_map(place_map: PlaceMap, lo: int, hi: int, name: str) -> PlaceMap:
    """``place_map``'s places [lo, hi) alone, as one drive ``name`` (no index, no SVM; its adaptation kept)."""
    from vpr_edge.index.encodings import Encodings

    stored = Encodings(np.ascontiguousarray(place_map.stored.values[lo:hi]), place_map.stored.storage,
                       None if place_map.stored.scale is None else np.array(place_map.stored.scale[lo:hi]))
    if place_map.positions is not None:
        raise ValueError("cutting a map with positions is not supported here")
    meta = {k: v for k, v in place_map.meta.items() if k not in ("svm", "index")}
    return PlaceMap(stored, place_map.names[lo:hi], place_map.encoder, meta, None, None,
                    Drives.single(name, hi - lo, None), None, adaptation=place_map.adaptation)


def link_frames(frames: Sequence[Path], folder: Path) -> None:
    """Symbolic links to ``frames`` in ``folder`` (made; emptied of links first), in order."""
    folder.mkdir(parents=True, exist_ok=True)
    for old in folder.iterdir():
        if old.is_symlink():
            old.unlink()
    for i, f in enumerate(frames):
        os.symlink(f.resolve(), folder / f"{i:07d}{f.suffix}")


def main(argv: Sequence[str] | None = None) -> int:
    p = parser(__name__, __doc__)
    p.add_argument("--streams", type=Path, required=True, help="a derived-streams folder: ref/, map.npz, aligned/")
    p.add_argument("--work", type=Path, required=True, help="where the drives, truths and maps are written")
    p.add_argument("--learn-half", default="first", choices=("first", "second"))
    p.add_argument("--rank", type=int, default=None, help="adapt --rank (default: its own)")
    p.add_argument("--threads", type=int, default=1)
    a = p.parse_args(argv)
    return run_checked(__name__, lambda: _run(a))


def split_halves(places: int, learn_half: str) -> tuple[tuple[int, int], tuple[int, int]]:
    """The places [lo, hi) learned from (``learn_half``) and those scored (the other half) of a route of
    ``places``: they share none."""
    return half_bounds(places, learn_half), half_bounds(places, other_half(learn_half))


Scores = dict[tuple[str, bool, int], tuple[float, float, float]]


def adapt_and_score(source_map: Path, learn: LabelledDrive, test: Path, test_gt: Path,
                    halves: tuple[tuple[int, int], tuple[int, int]], work: Path, rank: int | None = None,
                    threads: int = 1, test_name: str = "test") -> Scores:
    """Adapt ``source_map`` on the drive ``learn`` (WORK/adapted.npz), cut the plain and adapted maps to the
    scored places of ``halves`` (``split_halves``; WORK/test.plain.npz, WORK/test.adapted.npz, one drive
    ``test_name``) and score the frames ``test`` (labelled by ``test_gt`` against the cut maps) on each; prints
    the commands run and the table -> (map kind, standardised, tolerance) -> (single R@1, stream R@1, stream
    mapped right)."""
    (llo, lhi), (tlo, thi) = halves
    adapted = work / "adapted.npz"
    extra = [] if rank is None else ["--rank", str(rank)]
    print("$ vpr-edge adapt " + " ".join([str(source_map), learn.frames, "--gt", learn.truth, "-o", str(adapted)]
                                         + extra))
    kw = {} if rank is None else {"rank": rank}
    print(adapt_map(source_map, [learn], adapted, ort_threads=use_threads(threads), **kw))
    storage = load_map(source_map).stored.storage
    maps = {}
    for kind, path in (("plain", source_map), ("adapted", adapted)):
        maps[kind] = work / f"test.{kind}.npz"
        save_map(cut_map(load_map(path), tlo, thi, test_name), maps[kind], storage=storage)
    print(f"learned on places {llo}-{lhi - 1} ({lhi - llo} frames); tested on places {tlo}-{thi - 1} "
          f"({thi - tlo} frames, maps cut to them)")
    matchers = {m: get_matcher(m) for m in ("single", "stream")}
    print("| map | cosines | tolerance | single R@1 | stream R@1 | stream mapped right |")
    print("|---|---|---|---|---|---|")
    scores: Scores = {}
    for kind, path in maps.items():
        for std in (False, True):
            print(f"$ vpr-edge evaluate -m {path} -q {test} --gt {test_gt} --modes "
                  f"single,stream --tolerance T{' --standardise' if std else ' --raw-cosines'}")
            for tol in TOLERANCES:
                ev = evaluate(Source(map=path, queries=test, threads=threads, standardise=std), Truth(gt=test_gt),
                              matchers, tol)
                s, st = ev.reports["single"], ev.reports["stream"]
                scores[kind, std, tol] = (s.recall[1], st.recall[1], st.mapped_right)
                print(f"| {kind} | {'standardised' if std else 'raw'} | {tol} | {s.recall[1]:.3f} | "
                      f"{st.recall[1]:.3f} | {st.mapped_right:.3f} |")
    return scores


def _run(a: argparse.Namespace) -> int:
    frames = list_images(a.streams / "aligned")
    source_map = a.streams / "map.npz"
    n = len(load_map(source_map).names)
    if len(frames) != n:
        raise VprError(f"{a.streams}/aligned: {len(frames)} frames, but the map has {n} places")
    halves = (llo, lhi), (tlo, thi) = split_halves(n, a.learn_half)
    if lhi - llo < MIN_PAIRS:   # checked before anything is written
        raise VprError(f"{a.streams}/aligned: a half of {lhi - llo} frames, too short to learn from "
                       f"(at least {MIN_PAIRS})")
    a.work.mkdir(parents=True, exist_ok=True)
    link_frames(frames[llo:lhi], a.work / "learn")
    write_ground_truth(a.work / "learn.csv", [[i] for i in range(llo, lhi)])
    link_frames(frames[tlo:thi], a.work / "test")
    write_ground_truth(a.work / "test.csv", [[i] for i in range(thi - tlo)])
    adapt_and_score(source_map, LabelledDrive(str(a.work / "learn"), str(a.work / "learn.csv")), a.work / "test",
                    a.work / "test.csv", halves, a.work, a.rank, a.threads, f"{other_half(a.learn_half)}-half")
    return 0
