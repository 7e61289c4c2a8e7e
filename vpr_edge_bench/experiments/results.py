"""Re-measure the figures the README quotes, on the current code, from the shared datasets, and write them.

    python -m vpr_edge_bench results --datasets ../shared/datasets --out out/results --quick [--write-docs]

For each dataset (DATASETS/corridor, DATASETS/nordland-dev: ref/ and query/ aligned frame by frame) it derives
the streams a vehicle produces (``streams.derive_streams``, seed 0), builds the default map of the
first two thirds of its places (``map.make``: what ``vpr-edge build-map`` makes), and runs ``evaluate`` (the
library function behind ``vpr-edge evaluate``) on every stream with the ``stream`` matcher and online SeqSLAM
at tolerance 2 and 1. Then the speed yardstick: one fp32 inference of the 320x240 model on one thread
(``yardstick``) beside the default chain's time per frame once started (``Localizer.run``, one
thread, over each dataset's aligned stream), both in this run: the ratio is the figure.

``--quick`` is all of that (minutes on 2 cores). The full run (no ``--quick``) then runs every experiment of
``SECTIONS`` on those streams and maps, each the one that makes a generated table of docs/, and keeps what each
printed (OUT/sections/NAME.md, headed by the command, the commit and the machine; ``--sections`` runs some of
them only). OUT gets results.json (every figure, the commit and the machine) and results.md (the tables).
``--write-docs`` also copies results.json to docs/generated/results.json and rewrites from it the README's
results table and docs/results.md's answered-right table (``doc_tables``; a test checks that both hold exactly
the tables that file gives), and puts each section run between its markers in the document of docs/ that holds
them (``<!-- generated: NAME -->`` ... ``<!-- end of generated: NAME -->``).
"""
from __future__ import annotations

import datetime
import json
import os
import platform
import shlex
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vpr_edge.errors import VprError
from vpr_edge.map.make import BuildOptions, plan_map, write_map
from vpr_edge.matchers import get_matcher
from vpr_edge_bench.doc_tables import TABLE_END, TABLE_START, answers_table, readme_table, replace_between
from vpr_edge_bench.folder import StreamsFolder
from vpr_edge_bench.runner import PROG, parser, run_checked
from vpr_edge_bench.streams import KINDS, derive_streams
from vpr_edge_bench.yardstick import chain_ms, yardstick_ms

ROOT = Path(__file__).resolve().parents[2]   # the checkout: README.md, docs/, vpr_edge_bench/
DATASETS = ("corridor", "nordland-dev")
MODES = ("stream", "seqslam-online")
TOLERANCES = (2, 1)


@dataclass(frozen=True)
class Section:
    """A generated table of docs/ and the experiment that makes it: ``python -m vpr_edge_bench EXPERIMENT ARGS``,
    where ``{corridor}`` and ``{nordland-dev}`` stand for the run's derived-stream folders (each with its
    default map.npz) and ``{out}`` for OUT."""

    name: str
    experiment: str
    args: tuple[str, ...]
    setup: tuple[tuple[str, ...], ...] = ()   # ``python ARGS`` run first (e.g. exporting a model), same places
    fenced: bool = False                      # it prints plain text, not Markdown: kept as a code block


def _e2e(dataset: str) -> "Section":
    """bench-e2e on one dataset: the default and its int8 form, whole commands beside the yardstick."""
    return Section(f"e2e-{dataset}", "bench-e2e", ("--streams", f"{{{dataset}}}", "--config", "default=",
                                                   "--config", "default-int8=|--precision int8", "--out",
                                                   f"{{out}}/e2e-{dataset}"))


# The generated tables of docs/: the default chain's speed, the lost line on nine front ends (behind the hub,
# stuck and trust records of docs/decisions.md) and the million-place targets. The other experiments' figures
# are quoted in docs/ with their commands.
SECTIONS = (
    _e2e("nordland-dev"),
    _e2e("corridor"),
    Section("front-end-lines", "front-end-lines", ("--cache", "{out}/fronts", "--modes",
                                                   "stream,stream-rules,seqslam-online", "--ranges",
                                                   "--oracle"),
            setup=(("-m", "vpr_edge_bench", "front-end-cache", "--streams", "{corridor}", "{nordland-dev}",
                    "--out", "{out}/fronts"),)),   # the front ends' matrices (kept where made)
    Section("scale", "bench-scale", ("--work", "{out}/scale")),
)


def run_section(section: Section, out: Path, doc: dict) -> str:
    """Run one section's experiment in a process of its own (one BLAS / OpenMP thread, as the timings assume):
    its output, headed by the command, the commit and the machine. Raises VprError naming it if it fails."""
    places = {"{corridor}": str(out / "corridor"), "{nordland-dev}": str(out / "nordland-dev"), "{out}": str(out)}
    def placed(items: tuple[str, ...]) -> list[str]:
        out_args = list(items)
        for key, value in places.items():
            out_args = [a.replace(key, value) for a in out_args]
        return out_args

    args = placed(section.args)
    shown = " ".join([PROG, section.experiment, *[shlex.quote(places_back(a, out)) for a in args]])
    env = os.environ | {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
                        "PYTHONPATH": os.pathsep.join([str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])}
    t0 = time.perf_counter()
    def python(argv: list[str], what: str) -> str:
        done = subprocess.run([sys.executable, *argv], capture_output=True, text=True, env=env)
        if done.returncode != 0:
            last = (done.stderr.strip().splitlines() or ["no message"])[-1]
            raise VprError(f"{what} failed: {last}")
        return done.stdout

    for step in section.setup:
        first = placed(step)
        for a in first:
            if a.startswith(str(out)) and a.endswith(".onnx"):
                Path(a).parent.mkdir(parents=True, exist_ok=True)
        python(first, f"section {section.name}: python {' '.join(step[:2])}")
    stdout = python(["-m", "vpr_edge_bench", section.experiment, *args],
                    f"{PROG} {section.experiment} (section {section.name})")
    took = time.perf_counter() - t0
    doc.setdefault("sections", {})[section.name] = {"command": shown, "seconds": round(took, 1)}
    for step in reversed(section.setup):
        shown = " ".join(["python", *[shlex.quote(places_back(a, out)) for a in placed(step)]]) + "`, then `" + shown
    head = (f"Made by `{shown}` at commit {doc['commit']}{' (with local changes)' if doc['dirty'] else ''} on "
            f"{doc['machine']['cpu']} ({doc['machine']['cores']} cores), {doc['date']}, in {took:.0f} s:")
    text = stdout.strip()
    return head + "\n\n" + (f"```\n{text}\n```" if section.fenced else text) + "\n"


def places_back(arg: str, out: Path) -> str:
    """A path under OUT written as the docs name it (out/...)."""
    return arg.replace(str(out), "out")


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
            "dirty": bool(git("status", "--porcelain", "--", "vpr_edge", "vpr_edge_bench"))}


def figures(report) -> dict:
    """The figures of one matcher's ``ModeReport`` that the tables quote (from ``as_json``: evaluate --json's)."""
    js = report.as_json()
    return {"r1": js["recall_at_1"]} | {k: js[k] for k in ("auc", "answered_right", "mapped_right", "lost_unmapped",
                                                          "lost_mapped", "exit_frames", "lock_frames",
                                                          "one_view_frames", "distinct_answered_right",
                                                          "distinct_mapped_right")}


def measure(datasets: Path, out: Path) -> dict:
    """Every figure of the quick run (module docstring) as JSON-ready data."""
    doc: dict = {"tool": f"{PROG} results --quick", "date": datetime.date.today().isoformat(), **commit(),
                 "machine": machine(), "datasets": {}, "speed": {}}
    matchers = {m: get_matcher(m) for m in MODES}
    yard = [yardstick_ms()]
    for name in DATASETS:
        folder = StreamsFolder(out / name)
        counts = derive_streams(datasets / name, folder.path)
        write_map(plan_map(folder.ref, folder.map, BuildOptions(threads=0)))
        rows: dict = {kind: {} for kind in KINDS}
        for tol in TOLERANCES:
            for kind, ev in folder.evaluate(matchers, tol):
                for mode, report in ev.reports.items():
                    rows[kind].setdefault(mode, {})[str(tol)] = figures(report)
        doc["datasets"][name] = {"map_places": counts["map places"], "frames": {k: counts[k] for k in KINDS},
                                 "streams": rows}
        doc["speed"][name] = {"ms_per_frame": round(chain_ms(folder.map, folder.frames("aligned")), 3)}
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


def section_markers(name: str) -> tuple[str, str]:
    """The lines that open and close section ``name``'s generated text in a document of docs/."""
    return f"<!-- generated: {name} -->\n", f"<!-- end of generated: {name} -->"


def write_sections(made: dict[str, str]) -> None:
    """Each section run put between its markers, in the document of docs/ that holds them (VprError, before
    anything is written, for a section no document has markers for)."""
    from vpr_edge.files.atomic import atomic_output

    texts = {path: path.read_text() for path in sorted((ROOT / "docs").glob("*.md"))}
    where = {name: next((path for path, text in texts.items() if section_markers(name)[0] in text), None)
             for name in made}
    lost = [name for name, path in where.items() if path is None]
    if lost:
        raise VprError(f"docs/: no document has the markers of section {lost[0]!r} "
                       f"({section_markers(lost[0])[0].strip()})")
    for name, body in made.items():
        texts[where[name]] = replace_between(texts[where[name]], *section_markers(name), body, where[name])
    for path in set(where.values()):
        with atomic_output(path) as tmp:
            tmp.write_text(texts[path])


def write_docs(doc: dict) -> None:
    """docs/generated/results.json, and the README's and docs/results.md's tables rewritten from it
    (``doc_tables``)."""
    from vpr_edge.files.atomic import atomic_output

    gen = ROOT / "docs" / "generated"
    gen.mkdir(exist_ok=True)
    with atomic_output(gen / "results.json") as tmp:
        tmp.write_text(json.dumps(doc, indent=1) + "\n")
    for doc_file, table in ((ROOT / "README.md", readme_table(doc)),
                            (ROOT / "docs" / "results.md", answers_table(doc))):
        text = replace_between(doc_file.read_text(), TABLE_START, TABLE_END, table + "\n", doc_file)
        with atomic_output(doc_file) as tmp:
            tmp.write_text(text)


def main(argv: Sequence[str] | None = None) -> int:
    p = parser(__name__, __doc__)
    p.add_argument("--datasets", type=Path, default=ROOT.parent / "shared" / "datasets",
                   help="the folder holding corridor/ and nordland-dev/")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--quick", action="store_true", help="the derived streams' accuracy and the speed yardstick")
    p.add_argument("--sections", default=",".join(s.name for s in SECTIONS),
                   help="the full run's sections to run (comma-separated; default: all)")
    p.add_argument("--write-docs", action="store_true",
                   help="copy results.json to docs/generated/ and rewrite the README's results table from it")
    a = p.parse_args(argv)

    def run() -> int:
        known = {s.name: s for s in SECTIONS}   # everything checked before any work
        chosen = [n for n in a.sections.split(",") if n]
        unknown = [n for n in chosen if n not in known]
        if unknown:
            raise VprError(f"--sections: no section {unknown[0]!r} (sections: {', '.join(known)})")
        missing = [str(a.datasets / d) for d in DATASETS if not (a.datasets / d / "ref").is_dir()]
        if missing:
            raise VprError(f"{missing[0]}: not a dataset folder with ref/ and query/ (--datasets names their parent)")
        a.out.mkdir(parents=True, exist_ok=True)
        doc = measure(a.datasets, a.out)
        made: dict[str, str] = {}
        if not a.quick:
            doc["tool"] = f"{PROG} results"
            (a.out / "sections").mkdir(exist_ok=True)
            for name in chosen:
                made[name] = run_section(known[name], a.out, doc)
                (a.out / "sections" / f"{name}.md").write_text(made[name])
                print(f"section {name}: made", flush=True)
        (a.out / "results.json").write_text(json.dumps(doc, indent=1) + "\n")
        (a.out / "results.md").write_text(markdown(doc))
        if a.write_docs:
            if not a.quick:   # the sections not re-run stay in docs/ as they were: so do their entries
                kept = ROOT / "docs" / "generated" / "results.json"
                before = json.loads(kept.read_text()).get("sections", {}) if kept.exists() else {}
                doc["sections"] = {n: v for n, v in before.items() if n in known} | doc.get("sections", {})
            write_docs(doc)
            write_sections(made)
        print(markdown(doc))
        return 0
    return run_checked(__name__, run)

