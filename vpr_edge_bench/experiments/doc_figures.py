"""The pictures in docs/img/, re-made from the bundled Corridor sample in one command.

    python -m vpr_edge_bench doc-figures [--out docs/img]

A map of the sample's reference frames (build-map's defaults, no positions: as the README's quick start
makes it), its query frames evaluated against its ground truth (``evaluate``, tolerance 1) with four
matchers (stream, stream-rules, single, dtw), and the three figures ``evaluate`` draws: the PR curves
(``--plot``), the similarity matrix with each mode's answers (``--plot-matrix``) and where each mode puts the
vehicle frame by frame (``--plot-route`` on a map without positions). Each PNG must stay under ``MAX_KB``
(checked; the run fails otherwise). Needs the fit and plot extras. Bad input is one line on stderr and exit
code 2, before any work.
"""
from __future__ import annotations

import tempfile
from collections.abc import Sequence
from pathlib import Path

from vpr_edge.errors import VprError
from vpr_edge.evaluation import Source, Truth, evaluate, report
from vpr_edge.files.checks import check_writable
from vpr_edge.map.make import BuildOptions, plan_map, write_map
from vpr_edge.matchers import get_matcher
from vpr_edge.resources import sample_folder
from vpr_edge_bench.runner import parser, run_checked

MODES = ("stream", "stream-rules", "single", "dtw")
MAX_KB = 150
FIGURES = {"pr": "corridor_pr.png", "matrix": "corridor_matrix.png", "route": "corridor_route.png"}


def main(argv: Sequence[str] | None = None) -> int:
    p = parser(__name__, __doc__)
    p.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[2] / "docs" / "img",
                   help="folder the PNGs are written to (default: docs/img of this checkout)")
    a = p.parse_args(argv)
    return run_checked(__name__, lambda: _run(a.out))


def _run(out: Path) -> int:
    if not out.is_dir():
        raise VprError(f"{out}: not a folder")
    for name in FIGURES.values():
        check_writable(out / name)
    report.require_matplotlib()
    sample = sample_folder("corridor")
    with tempfile.TemporaryDirectory() as tmp:
        map_path = Path(tmp) / "corridor.map.npz"
        write_map(plan_map(sample / "ref", map_path, BuildOptions()))
        result = evaluate(Source(map=map_path, queries=sample / "query"), Truth(sample / "ground_truth.csv"),
                          {m: get_matcher(m) for m in MODES}, tolerance=1)
    title = report.figure_title(result.similarity.shape, map_path=map_path, queries=sample / "query")
    paths = {k: out / name for k, name in FIGURES.items()}
    report.plot(paths["pr"], result.reports, title)
    report.plot_matrix(paths["matrix"], result.similarity, result.truth, result.reports, title)
    report.plot_route(paths["route"], result.positions, result.truth, result.reports, title)
    too_big = []
    for path in paths.values():
        kb = path.stat().st_size / 1024
        print(f"{path.name}: {kb:.0f} KB")
        if kb > MAX_KB:
            too_big.append(f"{path.name} ({kb:.0f} KB)")
    if too_big:
        raise VprError(f"over {MAX_KB} KB: {', '.join(too_big)}")
    return 0

