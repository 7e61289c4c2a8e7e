"""A map of several drives against a one-folder map of the same places, on derived streams.

A map of several drives against a one-folder map of the same places (docs/results.md, "Maps of several
drives"), on derived streams, with the library's ``evaluate``.

    python -m vpr_edge_bench derive-streams --dataset ../shared/datasets/nordland-dev --out out/nordland-dev
    python -m vpr_edge_bench compare-drives --streams out/nordland-dev out/corridor --drives 4

For each dataset: the map's places (OUT/ref) are cut into ``--drives`` drives whose frames share names
(``streams.cut_into_drives``, OUT/drives/), given to build-map in a shuffled order; three maps are built: the
one-folder map (OUT/map.folder.npz), the drives with the one-folder map's codebook (OUT/map.drives.npz: the
same encodings, so only the handling of drives differs) and the drives with their own codebook fitted as
build-map fits it (OUT/map.drives-fit.npz), the first half of the drives built with their own fit and the
other half appended to it (OUT/map.drives-appended.npz: against the drives built at once); beside them the one-folder map fitted with another seed
(OUT/map.folder-seed1.npz: how much a codebook's random sample alone moves the figures). Each is run with the ``stream`` mode by ``evaluate`` on every
stream kind, and its answers are scored on the route (each answer's drive and name read back as the place of
the one-folder route it is, so that ``--tolerance`` counts along the road across a join as in the one-folder
map): R@1, and the frames wrong or lost in the ``--after`` frames after each join (a frame whose true place is
in another drive than the last mapped frame's), summed over the joins; then the matcher's ms a frame
(``evaluate``'s, whole stream) for each map; last, the whole per-frame chain (``Localizer`` on one thread over
the aligned stream, ``yardstick.chain_ms``) on the one-folder and the drives map, alternated three times.
With ``--append-seeds N`` it measures instead the drives built at once against half of them appended to the
other half, each fitted with codebook seeds 0..N-1 (mean and range of R@1 per stream).
"""
from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vpr_edge.errors import VprError
from vpr_edge.evaluation.metrics import correct_candidates
from vpr_edge.evaluation.truth import load_csv
from vpr_edge.map import load_map
from vpr_edge.map.make import BuildOptions, plan_map, write_map
from vpr_edge.matchers import get_matcher
from vpr_edge.threads import use_threads
from vpr_edge_bench.folder import StreamsFolder, streams_folders
from vpr_edge_bench.runner import parser, run_checked
from vpr_edge_bench.streams import DRIVES_FOLDER, KINDS, cut_into_drives
from vpr_edge_bench.yardstick import chain_ms


def joins(truth: np.ndarray, bounds: np.ndarray) -> list[int]:
    """Frames whose true place lies in another drive than the last mapped frame's (``bounds``: the drives'
    first places, then the number of places)."""
    out, last = [], None
    for i, row in enumerate(truth):
        if row[0] < 0:
            continue
        drive = int(np.searchsorted(bounds, row[0], side="right")) - 1
        if last is not None and drive != last:
            out.append(i)
        last = drive
    return out


def route_places(path: Path, bounds: np.ndarray) -> np.ndarray:
    """(R,) each place of the map at ``path`` as its place on the one-folder route: a drive k's frame_i is
    place bounds[k] + i; a one-folder map's places are the route's."""
    pm = load_map(path)
    if len(pm.drives) == 1:
        return np.arange(len(pm.names))
    drive = pm.drives.of_each()
    return np.array([bounds[int(pm.drives.items[d].name)] + int(Path(n).stem.split("_")[1])
                     for d, n in zip(drive, pm.names)])


def measure(folder: StreamsFolder, n_drives: int, tolerance: int, after: int, seed: int) -> list[str]:
    order = cut_into_drives(folder.path, n_drives, seed)
    codebook = folder.path / "codebook.folder.npz"
    maps = {name: folder.path / f"map.{stem}.npz" for name, stem in (
        ("one folder", "folder"), ("one folder, seed 1", "folder-seed1"), ("drives", "drives"),
        ("drives, own fit", "drives-fit"), ("2 drives + 2 appended", "drives-appended"))}
    write_map(plan_map(folder.ref, maps["one folder"], BuildOptions(threads=1, save_codebook=codebook)))
    write_map(plan_map(folder.ref, maps["one folder, seed 1"], BuildOptions(threads=1, seed=1)))
    write_map(plan_map(order, maps["drives"], BuildOptions(threads=1, codebook=codebook)))
    write_map(plan_map(order, maps["drives, own fit"], BuildOptions(threads=1)))
    half = len(order) // 2
    write_map(plan_map(order[:half], maps["2 drives + 2 appended"], BuildOptions(threads=1)))
    write_map(plan_map(order[half:], maps["2 drives + 2 appended"], BuildOptions(threads=1, append=True)))
    n_refs = len(list(folder.ref.iterdir()))
    bounds = np.linspace(0, n_refs, n_drives + 1).round().astype(int)
    stream = {"stream": get_matcher("stream")}
    truths = {kind: load_csv(folder.truth(kind)) for kind in folder.kinds}
    cells: dict[str, list[str]] = {kind: [] for kind in folder.kinds}
    for name, path in maps.items():
        places = route_places(path, bounds)
        drives = None if name.startswith("one folder") else folder.path / DRIVES_FOLDER
        for kind, ev in folder.evaluate(stream, tolerance, map=path, truth_in=drives, threads=1):
            report, truth = ev.reports["stream"], truths[kind]
            mapped = (truth >= 0).any(axis=1)
            right = correct_candidates(places[report.refs], truth, tolerance)[:, 0]
            bad = ~right | report.lost
            after_joins = sum(int((bad & mapped)[j:j + after].sum()) for j in joins(truth, bounds))
            cells[kind].append(f"{right[mapped].mean():.3f} / {after_joins} / {report.match_ms:.2f}")
    lines = [f"{folder.name}: {n_refs} places in {n_drives} drives given as "
             f"{' '.join(Path(d).name for d in order)}; `stream`, R@1 within ±{tolerance} / frames wrong or lost "
             f"in the {after} after the joins (joins) / matcher ms a frame", "",
             "| stream | joins | " + " | ".join(maps) + " |", "|---|---|" + "---|" * len(maps)]
    lines += [f"| {kind} | {len(joins(truths[kind], bounds))} | " + " | ".join(cells[kind]) + " |"
              for kind in folder.kinds]
    runs: dict[str, list[float]] = {"one folder": [], "drives": []}
    for _ in range(3):
        for name in runs:
            runs[name].append(chain_ms(maps[name], folder.frames("aligned")))
    one, many = (float(np.median(v)) for v in runs.values())
    lines += ["", f"Whole chain, one thread, aligned stream (median of 3, alternated): one folder {one:.2f} ms a "
              f"frame, drives {many:.2f} ms a frame ({many / one:.2f}x)."]
    return lines + [""]


def append_spread(folder: StreamsFolder, n_drives: int, tolerance: int, seeds: int) -> list[str]:
    """R@1 of the drives built at once and of half of them with the other half appended, each with its own
    codebook fitted with seeds 0..seeds-1: mean and range per stream (what a codebook's sample moves)."""
    order = cut_into_drives(folder.path, n_drives, 0)
    n_refs = len(list(folder.ref.iterdir()))
    bounds = np.linspace(0, n_refs, n_drives + 1).round().astype(int)
    stream = {"stream": get_matcher("stream")}
    kinds = folder.kinds
    r1: dict[str, dict[str, list[float]]] = {"at once": {k: [] for k in kinds}, "appended": {k: [] for k in kinds}}
    for seed in range(seeds):
        at_once, appended = folder.path / f"map.once-{seed}.npz", folder.path / f"map.appended-{seed}.npz"
        write_map(plan_map(order, at_once, BuildOptions(threads=1, seed=seed)))
        half = len(order) // 2
        write_map(plan_map(order[:half], appended, BuildOptions(threads=1, seed=seed)))
        write_map(plan_map(order[half:], appended, BuildOptions(threads=1, append=True)))
        for name, path in (("at once", at_once), ("appended", appended)):
            places = route_places(path, bounds)
            for kind, ev in folder.evaluate(stream, tolerance, map=path, truth_in=folder.path / DRIVES_FOLDER,
                                            threads=1):
                truth = load_csv(folder.truth(kind))
                right = correct_candidates(places[ev.reports["stream"].refs], truth, tolerance)[:, 0]
                r1[name][kind].append(float(right[(truth >= 0).any(axis=1)].mean()))
    lines = [f"{folder.name}: R@1 within ±{tolerance}, {n_drives} drives built at once against half of them "
             f"appended to the other half, codebook seeds 0..{seeds - 1}: mean (min-max)", "",
             "| stream | at once | appended | difference of the means |", "|---|---|---|---|"]
    for kind in kinds:
        a, b = np.array(r1["at once"][kind]), np.array(r1["appended"][kind])
        lines.append(f"| {kind} | {a.mean():.3f} ({a.min():.3f}-{a.max():.3f}) | {b.mean():.3f} ({b.min():.3f}-"
                     f"{b.max():.3f}) | {b.mean() - a.mean():+.3f} |")
    return lines + [""]


def main(argv: Sequence[str] | None = None) -> int:
    p = parser(__name__, __doc__)
    p.add_argument("--streams", type=Path, nargs="+", required=True, help="derived-streams folders")
    p.add_argument("--drives", type=int, default=4)
    p.add_argument("--kinds", default=",".join(KINDS))
    p.add_argument("--tolerance", type=int, default=2)
    p.add_argument("--after", type=int, default=15, help="frames after each join counted")
    p.add_argument("--seed", type=int, default=0, help="the drives' shuffled order")
    p.add_argument("--append-seeds", type=int, default=0, help="instead: appended against built at once, over "
                   "this many codebook seeds (append_spread)")
    a = p.parse_args(argv)
    return run_checked(__name__, lambda: _run(a))


def _run(a: argparse.Namespace) -> int:
    """The work of ``main``, inputs checked first: every folder's ref/ and the streams of --kinds."""
    if a.drives < 1 or a.append_seeds < 0:
        raise VprError(f"--drives must be >= 1 and --append-seeds >= 0, got {a.drives} and {a.append_seeds}")
    folders = streams_folders(a.streams, map=False, ref=True, kinds=[k for k in a.kinds.split(",") if k])
    use_threads(1)
    for folder in folders:
        lines = append_spread(folder, a.drives, a.tolerance, a.append_seeds) if a.append_seeds else \
            measure(folder, a.drives, a.tolerance, a.after, a.seed)
        print("\n".join(lines), flush=True)
    return 0
