"""Front ends side by side on derived streams: accuracy, bytes a place and ms a frame per model.

Front ends side by side on derived streams (docs/results.md, "A global front end"): one map per model,
evaluated by the library's ``evaluate`` on every derived stream, with the bytes a place and ms a frame.

    python -m vpr_edge_bench derive-streams --dataset ../shared/datasets/nordland-dev --out out/nordland-dev
    python -m vpr_edge_export.onnx_export --architecture gem --backbone efficientnet_lite0 --tap stage5 \\
        --width 160 --height 120 --out out/models/lite0_stage5_gem_160x120.onnx
    python -m vpr_edge_bench compare-front-ends --streams out/nordland-dev out/corridor \\
        --front default --front gem=out/models/lite0_stage5_gem_160x120.onnx

``--front NAME=MODEL`` builds ``OUT/map.NAME.npz`` with ``--model MODEL`` (``default``: the default build, no
model given). For each dataset it prints, per front end, the ``stream`` mode's R@1 within the tolerance,
answered right, mapped right and unmapped lost per stream, and ``single``'s R@1 (the front end alone); then
bytes a place and ms a frame (``Localizer`` on one thread over the aligned stream, after the first frame)
beside the yardstick measured in the same run (one fp32 inference of the bundled 320x240 model).
"""
from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from vpr_edge.errors import VprError
from vpr_edge.map import load_map
from vpr_edge.map.make import BuildOptions, plan_map, write_map
from vpr_edge.matchers import get_matcher
from vpr_edge.threads import use_threads
from vpr_edge_bench.folder import streams_folders
from vpr_edge_bench.runner import parser, run_checked
from vpr_edge_bench.streams import KINDS
from vpr_edge_bench.yardstick import chain_ms, yardstick_ms


def fronts(given: list[str]) -> dict[str, Path | None]:
    out: dict[str, Path | None] = {}
    for item in given:
        name, _, model = item.partition("=")
        if name != "default" and not model:
            raise VprError(f"--front {item}: expected NAME=MODEL.onnx (or default)")
        if model and not Path(model).is_file():
            raise VprError(f"{model}: model file not found")
        out[name] = Path(model) if model else None
    return out


def run(a: argparse.Namespace) -> int:
    use_threads(1)
    models = fronts(a.front)
    folders = streams_folders(a.streams, map=False, ref=True)
    matchers = {m: get_matcher(m) for m in ("single", "stream")}
    for folder in folders:
        yard = [yardstick_ms()]
        rows: dict[str, dict] = {}
        for name, model in models.items():
            map_path = folder.path / f"map.{name}.npz"
            write_map(plan_map(folder.ref, map_path, BuildOptions(model=model, threads=1)))
            per_kind = {kind: {m: r.as_json() for m, r in ev.reports.items()}
                        for kind, ev in folder.evaluate(matchers, a.tolerance, map=map_path)}
            rows[name] = {"streams": per_kind, "bytes": load_map(map_path).stored.bytes_per_place,
                          "ms": chain_ms(map_path, folder.frames("aligned"))}
        yard.append(yardstick_ms())
        ref = sum(yard) / len(yard)
        print(f"\n{folder.name}, tolerance ±{a.tolerance}: stream R@1 / answered right / mapped right / unmapped "
              f"lost; single R@1\n")
        print("| front end | " + " | ".join(KINDS) + " |")
        print("|---|" + "---|" * len(KINDS))
        for name, r in rows.items():
            cells = []
            for kind in KINDS:
                s, one = r["streams"][kind]["stream"], r["streams"][kind]["single"]
                vals = [s["recall_at_1"], s["answered_right"], s["mapped_right"], s["lost_unmapped"]]
                cells.append(" / ".join("-" if v is None else f"{v:.2f}" for v in vals) + f"; {one['recall_at_1']:.2f}")
            print(f"| {name} | " + " | ".join(cells) + " |")
        print()
        for name, r in rows.items():
            print(f"{name}: {r['bytes']} bytes a place, {r['ms']:.2f} ms a frame = {r['ms'] / ref:.2f}x the "
                  f"yardstick ({' / '.join(f'{y:.2f}' for y in yard)} ms before / after)")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    p = parser(__name__, __doc__)
    p.add_argument("--streams", type=Path, nargs="+", required=True, help="derived-streams folders")
    p.add_argument("--front", action="append", required=True, help="NAME=MODEL.onnx, or default")
    p.add_argument("--tolerance", type=int, default=2)
    return run_checked(__name__, lambda: run(p.parse_args(argv)))

