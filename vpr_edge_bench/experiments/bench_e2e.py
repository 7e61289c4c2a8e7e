"""Per configuration, build-map and localize timed as whole commands, with accuracy, beside the yardstick.

End to end, per configuration: build-map time and bytes a place, then on every derived stream the
`localize --threads 1` wall time per frame and the `evaluate --tolerance T` accuracy, beside the yardstick
(one fp32 inference of the bundled 320x240 model on one thread, measured in the same run).

    python -m vpr_edge_bench derive-streams --dataset ../shared/datasets/nordland-dev --out out/nordland-dev
    python -m vpr_edge_bench bench-e2e --streams out/nordland-dev --config default= \\
        --config "thesis=--model vpr_edge/models/efficientnet_lite0_stage5_320x240.onnx --components 128 --pca-dim 0"

A configuration is NAME=BUILD-MAP OPTIONS (empty: the defaults); ``NAME=...|LOCALIZE OPTIONS`` adds options
to localize and evaluate (e.g. ``|--precision fp32``). Each map is built from STREAMS/ref into OUT (default
STREAMS/bench) with ``--threads`` (default 2) and timed as a whole command. Localize is timed as a whole
command over each stream (start-up included: ``startup`` is the same command over a one-frame stream) and
per frame once started ((wall - startup) / (frames - 1)). The floor of any whole command is also measured:
a Python that only imports numpy, onnxruntime and cv2 (what reading frames and running the model need); the
last column is what a whole command would cost per frame if its start-up were that floor alone. Prints a
Markdown table; OUT/bench.json keeps it.
"""
from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vpr_edge.errors import VprError
from vpr_edge_bench.folder import StreamsFolder
from vpr_edge_bench.runner import parser, run_checked
from vpr_edge_bench.streams import KINDS
from vpr_edge_bench.yardstick import yardstick_ms


def timed(cmd: list[str], env: dict) -> float:
    """Wall seconds of the command ``cmd``; VprError with its last line of stderr if it fails."""
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    if proc.returncode:
        last = (proc.stderr.strip().splitlines() or ["no message"])[-1]
        raise VprError(f"{' '.join(cmd)} failed: {last}")
    return wall


def main(argv: Sequence[str] | None = None) -> int:
    p = parser(__name__, __doc__)
    p.add_argument("--streams", type=Path, required=True, help="a derived-streams folder: ref/, KIND/, KIND.csv")
    p.add_argument("--config", action="append", required=True, help="NAME=BUILD-MAP OPTIONS[|RUN OPTIONS]")
    p.add_argument("--kinds", default=",".join(KINDS))
    p.add_argument("--tolerance", default="2")
    p.add_argument("--threads", default="2", help="build-map's threads")
    p.add_argument("--out", type=Path, default=None)
    a = p.parse_args(argv)
    return run_checked(__name__, lambda: _run(a))


def _run(a: argparse.Namespace) -> int:
    """The work of ``main``, the folder checked first."""
    folder = StreamsFolder(a.streams, [k for k in a.kinds.split(",") if k]).check(map=False, ref=True)
    kinds = folder.kinds
    out = a.out or folder.path / "bench"
    out.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, OMP_NUM_THREADS="1")
    exe = [sys.executable, "-m", "vpr_edge"]
    yard = [yardstick_ms()]
    floor_s = min(timed([sys.executable, "-c", "import numpy, onnxruntime, cv2"], env) for _ in range(5))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        one = Path(tmp) / "one"
        one.mkdir()
        first = sorted(folder.frames(kinds[0]).iterdir())[0]
        (one / first.name).write_bytes(first.read_bytes())
        for config in a.config:
            name, _, rest = config.partition("=")
            build_opts, _, run_opts = rest.partition("|")
            map_path = out / f"{name}.npz"
            map_path.unlink(missing_ok=True)
            build_s = timed([*exe, "build-map", str(folder.ref), "-o", str(map_path), "--threads", a.threads,
                             *shlex.split(build_opts)], env)
            info = json.loads(subprocess.run([*exe, "info", str(map_path)], capture_output=True, text=True,
                                             env=env).stdout)
            run = shlex.split(run_opts)
            loc = [*exe, "localize", "--map", str(map_path), "--threads", "1", *run, "--out"]
            startup = min(timed([*loc, str(Path(tmp) / "o.csv"), "--stream", str(one)], env) for _ in range(2))
            row = {"config": name, "build_options": build_opts, "run_options": run_opts, "build_s": build_s,
                   "bytes_per_place": info["bytes_per_place"], "startup_s": startup, "streams": {}}
            for kind in kinds:
                frames = len(list(folder.frames(kind).iterdir()))
                wall = timed([*loc, str(Path(tmp) / "o.csv"), "--stream", str(folder.frames(kind))], env)
                js = Path(tmp) / "e.json"
                timed([*exe, "evaluate", "--map", str(map_path), "--queries", str(folder.frames(kind)), "--gt",
                       str(folder.truth(kind)), "--modes", "stream", "--tolerance", a.tolerance,
                       "--threads", "1", *run, "--json", str(js)], env)
                doc = json.loads(js.read_text())
                r = doc["modes"]["stream"]
                row["model"], row["form"] = doc["front_end"]["model"], doc["front_end"]["form"]
                row["streams"][kind] = {"frames": frames, "wall_ms": 1e3 * wall / frames,
                                        "frame_ms": 1e3 * (wall - startup) / max(frames - 1, 1),
                                        "r1": r["recall_at_1"], "auc": r["auc"],
                                        "lost_unmapped": r["lost_unmapped"], "lost_mapped": r["lost_mapped"]}
            rows.append(row)
            print(json.dumps(row), file=sys.stderr, flush=True)
    yard.append(yardstick_ms())
    y = float(np.mean(yard))
    lines = [f"{a.streams}: stream mode, tolerance {a.tolerance}; yardstick (one fp32 inference of the 320x240 "
             f"model, one thread) {yard[0]:.1f} ms before, {yard[1]:.1f} ms after", "",
             "| configuration | model run | " + " | ".join(kinds) + " | ms/frame (whole command) | ms/frame once "
             "started | × yardstick | start-up s | bytes/place | build-map s | × yardstick at the import floor |",
             "|---|---|" + "---|" * len(kinds) + "---|---|---|---|---|---|---|"]
    for r in rows:
        s = r["streams"]
        wall = np.mean([s[k]["wall_ms"] for k in kinds])
        frame = np.mean([s[k]["frame_ms"] for k in kinds])
        at_floor = np.mean([s[k]["frame_ms"] + 1e3 * floor_s / s[k]["frames"] for k in kinds])
        lines.append(f"| {r['config']} | {r['model']} ({r['form'].split(':')[0]}) | "
                     + " | ".join(f"{s[k]['r1']:.3f} / {s[k]['auc']:.3f}" for k in kinds)
                     + f" | {wall:.1f} | {frame:.1f} | {frame / y:.2f} | {r['startup_s']:.2f} | "
                       f"{r['bytes_per_place']:,} | {r['build_s']:.1f} | {at_floor / y:.2f} |")
    lines += ["", "Cells: R@1 / AUC. ms/frame: mean over the streams; × yardstick: once started. Import floor "
              f"(python -c 'import numpy, onnxruntime, cv2', best of 5): {floor_s:.3f} s."]
    if "detour" in kinds:
        lines += ["", "detour, share of frames reported lost (unmapped / mapped): " + "; ".join(
            f"{r['config']} {r['streams']['detour']['lost_unmapped']:.3f} / {r['streams']['detour']['lost_mapped']:.3f}"
            for r in rows)]
    text = "\n".join(lines)
    (out / "bench.md").write_text(text + "\n")
    (out / "bench.json").write_text(json.dumps({"yardstick_ms": yard, "import_floor_s": floor_s, "rows": rows},
                                               indent=1) + "\n")
    print(text)
    return 0

