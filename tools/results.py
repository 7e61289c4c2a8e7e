#!/usr/bin/env python3
"""Re-measure the figures the README quotes, on the current code, from the shared datasets, and write them.

    python tools/results.py --datasets ../shared/datasets --out out/results --quick [--write-docs]

For each dataset (DATASETS/corridor, DATASETS/nordland-dev: ref/ and query/ aligned frame by frame) it derives
the streams a vehicle produces (``evaluation.streams.derive_streams``, seed 0), builds the default map of the
first two thirds of its places (``map.make``: what ``vpr-edge build-map`` makes), and runs ``evaluate`` (the
library function behind ``vpr-edge evaluate``) on every stream with the ``stream`` matcher and online SeqSLAM
at tolerance 2 and 1. Then the speed yardstick: one fp32 inference of the 320x240 model on one thread
(``evaluation.yardstick``) beside the default chain's time per frame once started (``Localizer.run``, one
thread, over each dataset's aligned stream), both in this run: the ratio is the figure.

``--quick`` is all of that (minutes on 2 cores); the full run (no ``--quick``) is the same today: the other
tables of docs/results.md keep the command each was measured with. OUT gets results.json (every figure, the
commit and the machine) and results.md (the tables). ``--write-docs`` also copies results.json to
docs/generated/results.json and rewrites from it the README's results table and docs/results.md's
answered-right table (a test checks that both hold exactly the tables that file gives).
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
from pathlib import Path

import numpy as np

from vpr_edge.errors import VprError, one_line_errors
from vpr_edge.evaluation import Source, Truth, evaluate
from vpr_edge.evaluation.report import answers_table, readme_table
from vpr_edge.evaluation.streams import KINDS, derive_streams
from vpr_edge.evaluation.yardstick import chain_ms, yardstick_ms
from vpr_edge.map.make import BuildOptions, plan_map, write_map
from vpr_edge.matchers import get_matcher

ROOT = Path(__file__).resolve().parent.parent
DATASETS = ("corridor", "nordland-dev")
MODES = ("stream", "seqslam-online")
TOLERANCES = (2, 1)


def machine() -> dict:
    """The CPU model and core count this run measured on."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"cpu": cpu, "cores": os.cpu_count()}


def commit() -> dict:
    """The checkout's commit and whether it had uncommitted changes (None outside a git checkout)."""
    def git(*args: str) -> str | None:
        try:
            return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, check=True).stdout.strip()
        except (OSError, subprocess.CalledProcessError):
            return None
    return {"commit": git("rev-parse", "--short", "HEAD"),
            "dirty": bool(git("status", "--porcelain", "--", "vpr_edge"))}


def figures(report) -> dict:
    """The figures of one matcher's ``ModeReport`` that the tables quote (from ``as_json``: evaluate --json's)."""
    js = report.as_json()
    return {"r1": js["recall_at_1"]} | {k: js[k] for k in ("auc", "answered_right", "mapped_right", "lost_unmapped",
                                                          "lost_mapped", "exit_frames", "lock_frames")}


def measure(datasets: Path, out: Path) -> dict:
    """Every figure of the quick run (module docstring) as JSON-ready data."""
    doc: dict = {"tool": "tools/results.py --quick", "date": datetime.date.today().isoformat(), **commit(),
                 "machine": machine(), "datasets": {}, "speed": {}}
    matchers = {m: get_matcher(m) for m in MODES}
    yard = [yardstick_ms()]
    for name in DATASETS:
        folder = out / name
        counts = derive_streams(datasets / name, folder)
        map_path = folder / "map.npz"
        write_map(plan_map(folder / "ref", map_path, BuildOptions(threads=0)))
        rows: dict = {}
        for kind in KINDS:
            for tol in TOLERANCES:
                ev = evaluate(Source(map=map_path, queries=folder / kind), Truth(gt=folder / f"{kind}.csv"),
                              matchers, tol)
                for mode, report in ev.reports.items():
                    rows.setdefault(kind, {}).setdefault(mode, {})[str(tol)] = figures(report)
        doc["datasets"][name] = {"map_places": counts["map places"], "frames": {k: counts[k] for k in KINDS},
                                 "streams": rows}
        doc["speed"][name] = {"ms_per_frame": round(chain_ms(map_path, folder / "aligned"), 3)}
        print(f"{name}: measured", flush=True)
    yard.append(yardstick_ms())
    doc["speed"]["yardstick_ms"] = [round(y, 3) for y in yard]
    for name in DATASETS:
        doc["speed"][name]["x_yardstick"] = round(doc["speed"][name]["ms_per_frame"] / float(np.mean(yard)), 3)
    return doc


def markdown(doc: dict) -> str:
    """results.md: where and when, the README's table, then per dataset the lost figures at tolerance 2."""
    lines = [f"Measured by `{doc['tool']}` at commit {doc['commit']}{' (with local changes)' if doc['dirty'] else ''} "
             f"on {doc['machine']['cpu']} ({doc['machine']['cores']} cores), {doc['date']}.", "",
             "R@1 within ±2 / ±1, default map, each dataset's derived streams:", "", readme_table(doc), ""]
    for name, data in doc["datasets"].items():
        lines += [f"{name} ({data['map_places']}-place map), `stream` at ±2: answered right / mapped right / "
                  "unmapped lost / mapped lost:", "", "| stream | answered right | mapped right | unmapped lost | "
                  "mapped lost |", "|---|---|---|---|---|"]
        for kind, modes in data["streams"].items():
            f = modes["stream"]["2"]
            cells = [f[k] for k in ("answered_right", "mapped_right", "lost_unmapped", "lost_mapped")]
            lines.append(f"| {kind} | " + " | ".join("-" if v is None else f"{v:.3f}" for v in cells) + " |")
        lines.append("")
    speed = doc["speed"]
    lines.append(f"Speed, one thread: yardstick (one fp32 inference of the 320×240 model) "
                 f"{' / '.join(f'{y:.2f}' for y in speed['yardstick_ms'])} ms (before / after); default chain once "
                 "started: " + "; ".join(f"{n} {speed[n]['ms_per_frame']:.2f} ms a frame = "
                                         f"{speed[n]['x_yardstick']:.2f}× the yardstick" for n in DATASETS) + ".")
    return "\n".join(lines) + "\n"


def write_docs(doc: dict) -> None:
    """docs/generated/results.json, and the README's results table rewritten from it."""
    from vpr_edge.files import atomic_output

    gen = ROOT / "docs" / "generated"
    gen.mkdir(exist_ok=True)
    with atomic_output(gen / "results.json") as tmp:
        tmp.write_text(json.dumps(doc, indent=1) + "\n")
    for doc_file, table in ((ROOT / "README.md", readme_table(doc)),
                            (ROOT / "docs" / "results.md", answers_table(doc))):
        text = doc_file.read_text()
        start, end = "<!-- results table: tools/results.py -->\n", "<!-- end of results table -->"
        if start not in text or end not in text:
            raise VprError(f"{doc_file}: the results table's markers are missing")
        head, rest = text.split(start)
        _, tail = rest.split(end)
        with atomic_output(doc_file) as tmp:
            tmp.write_text(head + start + table + "\n" + end + tail)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--datasets", type=Path, default=ROOT.parent / "shared" / "datasets",
                   help="the folder holding corridor/ and nordland-dev/")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--quick", action="store_true", help="the derived streams' accuracy and the speed yardstick")
    p.add_argument("--write-docs", action="store_true",
                   help="copy results.json to docs/generated/ and rewrite the README's results table from it")
    a = p.parse_args()

    def run() -> int:
        missing = [str(a.datasets / d) for d in DATASETS if not (a.datasets / d / "ref").is_dir()]
        if missing:   # checked before any work
            raise VprError(f"{missing[0]}: not a dataset folder with ref/ and query/ (--datasets names their parent)")
        a.out.mkdir(parents=True, exist_ok=True)
        doc = measure(a.datasets, a.out)
        (a.out / "results.json").write_text(json.dumps(doc, indent=1) + "\n")
        (a.out / "results.md").write_text(markdown(doc))
        if a.write_docs:
            write_docs(doc)
        print(markdown(doc))
        return 0
    return one_line_errors("results", run)


if __name__ == "__main__":
    raise SystemExit(main())
