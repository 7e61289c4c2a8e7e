"""``vpr-edge bench MAP``: every setting this machine offers (each precision the map's model has a form of,
1 .. N threads) timed in a process of its own (``stages``), then the setting picked for a frame rate.

The pick for ``fps`` F: among the settings whose mean frame sustains F frames a second, fp32 before int8 (int8
costs accuracy: docs/results.md, "The default"), then the fewest threads (the rest of the vehicle keeps the
other cores), then the fastest. None when no setting sustains F.
"""
from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from vpr_edge.errors import InputError, VprError
from vpr_edge.profiling.inputs import FramePlan, plan_frames

DEFAULT_FRAMES = 50
RECORD_SCHEMA = 1
# ARM cores by their /proc/cpuinfo "CPU part" (implementer 0x41, Arm): the boards vpr-edge is deployed on
ARM_PARTS = {"0xd03": "Cortex-A53", "0xd04": "Cortex-A35", "0xd05": "Cortex-A55", "0xd07": "Cortex-A57",
             "0xd08": "Cortex-A72", "0xd0b": "Cortex-A76", "0xd0c": "Neoverse-N1", "0xd41": "Cortex-A78",
             "0xd42": "Cortex-A78AE", "0xd46": "Cortex-A510", "0xd47": "Cortex-A710"}


@dataclass(frozen=True)
class BenchPlan:
    """What ``run_bench`` times: the map, its frames (``inputs.FramePlan``, ``count`` of them a setting), the
    precisions (None: a front end without one) and thread counts, what ``--precision auto`` runs here, the
    map's size, and the frame rate asked (None: none)."""

    map_path: Path
    frames: FramePlan
    count: int
    precisions: tuple[str | None, ...]
    threads: tuple[int, ...]
    auto: str | None
    map_info: dict
    fps: float | None


def plan_bench(map_path: str | os.PathLike[str], frames: int = DEFAULT_FRAMES, max_threads: int | None = None,
               fps: float | None = None) -> BenchPlan:
    """Check everything before the work (VprError, one line: a frame rate or frame count not above 0, more
    threads than this process's cores, a file that is no map, a model that is not the map's) and decide the
    settings: fp32, and int8 where the map's model has an int8 form made from it; 1 .. ``max_threads``
    threads (default: every core this process may use)."""
    from vpr_edge.features.choice import choose_form
    from vpr_edge.map import load_map
    from vpr_edge.map.front import map_front_end
    from vpr_edge.threads import cores

    if fps is not None and not fps > 0:
        raise InputError("{opt.fps} {fps:g}: give the camera's frame rate, above 0 (e.g. {opt.fps} 20)", fps=fps)
    if frames < 1:
        raise InputError("{opt.frames} {frames}: time at least one frame", frames=frames)
    n = cores()
    if max_threads is not None and not 1 <= max_threads <= n:
        raise InputError("{opt.max_threads} {m}: this process may use {n} core(s); bench times 1 to {n} threads "
                         "(more threads than cores only take turns)", m=max_threads, n=n)
    path = Path(map_path)
    place_map = load_map(path, mmap=True)
    precisions: tuple[str | None, ...] = (None,)
    auto = None
    if place_map.features.get("name") == "cnn":
        front = map_front_end(place_map, path, precision="fp32")      # the model is here and is the map's
        precisions = ("fp32",)
        try:
            map_front_end(place_map, path, precision="int8")           # its int8 form, made from it, is here
            precisions = ("fp32", "int8")
        except VprError:
            pass
        auto = choose_form(front.path, "auto")[1]
    places, dims = place_map.stored.shape
    info = {"path": str(path), "places": places, "dims": dims, "front_end": place_map.features.get("name"),
            "encoding": (place_map.meta.get("encoding") or {}).get("name"), "storage": place_map.stored.storage,
            "bytes_per_place": place_map.stored.bytes_per_place,
            "encodings_mb": round(places * place_map.stored.bytes_per_place / 1e6, 2),
            "file_mb": round(path.stat().st_size / 1e6, 2)}
    return BenchPlan(path, plan_frames(place_map, path, frames), frames, precisions,
                     tuple(range(1, (max_threads or n) + 1)), auto, info, fps)


def run_setting(plan: BenchPlan, precision: str | None, threads: int) -> dict:
    """One setting timed in a fresh Python process (``stages``); VprError with its message if it fails."""
    spec = {"map": str(plan.map_path), "plan": plan.frames.to_json(), "precision": precision, "threads": threads,
            "frames": plan.count, "spawned": time.time()}
    import vpr_edge

    here = str(Path(vpr_edge.__file__).resolve().parent.parent)     # the child runs this very package
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([here, *filter(None, [os.environ.get("PYTHONPATH")])]))
    proc = subprocess.run([sys.executable, "-m", "vpr_edge.profiling.stages"], input=json.dumps(spec),
                          capture_output=True, text=True, env=env)
    if proc.returncode != 0:
        lines = [line for line in proc.stderr.splitlines() if line.strip()]
        raise VprError(f"{plan.map_path}: timing {precision or ''} {threads} thread(s) failed: "
                       f"{lines[-1] if lines else f'exit code {proc.returncode}'}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def pick(rows: list[dict], fps: float) -> dict | None:
    """The setting for ``fps`` frames a second (the module's rule), or None if none sustains it."""
    able = [r for r in rows if r["fps"] >= fps]
    return min(able, key=lambda r: (r["precision"] == "int8", r["threads"], r["frame_ms"])) if able else None


def _cpu_name() -> str:
    """The CPU's model: x86's "model name", an ARM core's name from its part number, else the machine."""
    try:
        text = Path("/proc/cpuinfo").read_text(errors="replace")
    except OSError:
        return platform.processor() or platform.machine()
    fields: dict[str, str] = {}
    for line in text.splitlines():
        key, _, value = line.partition(":")
        fields.setdefault(key.strip().lower(), value.strip())
    if fields.get("model name"):
        return fields["model name"]
    part = fields.get("cpu part")
    if part:
        return ARM_PARTS.get(part.lower(), f"ARM CPU part {part}") if fields.get("cpu implementer") == "0x41" \
            else f"ARM CPU implementer {fields.get('cpu implementer')} part {part}"
    return platform.processor() or platform.machine()


def host() -> dict:
    """The machine the figures belong to: name, architecture, CPU, cores, int8 dot products, versions."""
    import numpy
    import onnxruntime

    from vpr_edge import __version__
    from vpr_edge.features.choice import int8_dot_product
    from vpr_edge.threads import cores

    return {"hostname": platform.node(), "machine": platform.machine(), "cpu": _cpu_name(), "cores": cores(),
            "int8_dot_product": int8_dot_product(), "python": platform.python_version(),
            "numpy": numpy.__version__, "onnxruntime": onnxruntime.__version__, "vpr_edge": __version__}


def run_bench(plan: BenchPlan, on_row: Callable[[dict], None] = lambda row: None) -> dict:
    """Time every setting of ``plan`` (``on_row`` told of each as it is done); the record: schema, when, the
    host, the map, the frames, every setting's figures and, for a frame rate asked, the pick."""
    rows = []
    for precision in plan.precisions:
        for threads in plan.threads:
            rows.append(run_setting(plan, precision, threads))
            on_row(rows[-1])
    frames = {"count": plan.count, "kind": plan.frames.kind, "where": plan.frames.where,
              "stages": list(plan.frames.stages)}
    if plan.frames.kind == "synthetic":
        frames["size"] = list(plan.frames.size)
    record = {"schema": RECORD_SCHEMA, "kind": "vpr-edge bench", "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
              "host": host(), "map": plan.map_info, "frames": frames, "precision_auto_here": plan.auto,
              "settings": rows, "fps_asked": plan.fps}
    if plan.fps is not None:
        record["pick"] = pick(rows, plan.fps)
    return record


def _cell(value: float | None, width: int, digits: int = 1) -> str:
    return f"{'-':>{width}}" if value is None else f"{value:{width}.{digits}f}"


def header_lines(plan: BenchPlan, machine: dict) -> list[str]:
    """What is timed, said before the figures."""
    m = plan.map_info
    lines = [f"{m['path']}: {m['places']:,} places, {m['front_end']} + {m['encoding']}, {m['dims']} dims stored "
             f"{m['storage']}: {m['bytes_per_place']:,} bytes a place ({m['encodings_mb']:,} MB of encodings)",
             f"{machine['machine']}, {machine['cpu']}, {machine['cores']} core(s); int8 dot products: "
             f"{machine['int8_dot_product'] or 'none'}"
             + (f"; --precision auto here: {plan.auto}" if plan.auto else ""),
             f"frames: {plan.count} a setting, {plan.frames.where}",
             "precision threads  decode   front  encode   match  ms/frame  p95 ms     fps  start-up s  "
             "1st frame ms  peak MB  now MB"]
    return lines


def row_line(row: dict) -> str:
    """One setting's figures, under ``header_lines``' last line."""
    s = row["stages_ms"]
    return (f"{row['precision'] or '-':<9s} {row['threads']:7d} " + " ".join(_cell(s[k], 7, 2) for k in s)
            + f" {row['frame_ms']:9.2f} {row['p95_ms']:7.2f} {row['fps']:7.1f} {row['startup_s']:11.2f} "
              f"{row['first_frame_ms']:13.1f} {row['peak_rss_mb']:8.1f} {_cell(row['rss_mb'], 7)}")


def verdict_line(record: dict) -> str:
    """The pick for the frame rate asked, or the fastest setting when none was asked."""
    def named(r: dict) -> str:
        precision = f"{r['precision']}, " if r["precision"] else ""
        return f"{precision}{r['threads']} thread(s) ({r['fps']:.1f} fps, p95 {r['p95_ms']:.1f} ms)"

    fastest = min(record["settings"], key=lambda r: r["frame_ms"])
    fps = record.get("fps_asked")
    if fps is None:
        return f"fastest: {named(fastest)}; --fps F picks the setting for a camera of F frames a second"
    chosen = record.get("pick")
    if chosen is None:
        return f"for {fps:g} fps: no setting sustains it here (fastest: {named(fastest)})"
    return (f"for {fps:g} fps: {named(chosen)}: localize --threads {chosen['threads']}"
            + (f" --precision {chosen['precision']}" if chosen["precision"] else ""))
