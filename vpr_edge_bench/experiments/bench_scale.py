"""A country-scale route end to end: build-map and localize over descriptor files, timed and scored.

    python -m vpr_edge_bench bench-scale --work out/scale --places 1000000 --frames 10000

Writes (once; kept and reused while their sizes match) a synthetic route of --places unit descriptors of --dim
dims and a hard stream over it (``synthetic``: cold start, speed changes, two detours off the map,
the second re-entering far away, a long stop of new exposures; a frame alone right about 1 time in 4), then:

1. ``vpr-edge build-map ROUTE.npy -o MAP`` as a command: wall time and peak RSS (its index included);
2. ``vpr-edge localize --threads 1 --map MAP --stream QUERIES.npy -o OUT.csv --min-confidence 0`` as a command:
   wall time (start-up included) a frame, its RssAnon / RssFile sampled every 0.2 s (max and last); every line
   keeps its best answer, and a frame is lost below the mode's own line (what localize reports by default);
3. the same stream through ``Localizer.push_encoding`` in this process, each frame timed: p50 / p99 / max ms and
   RssAnon at checkpoints (flat or not);
4. the yardstick (one fp32 inference of the 320x240 model, one thread) measured after them, every time printed
   beside it as a ratio;
5. the localize output scored against the ground truth: R@1 within +-2 over mapped frames (the best answers,
   sure or not), answers given right, mapped frames answered right, off-map frames reported lost, frames from
   leaving the map to the first lost one and from each re-entry to the first right answer.

--standardise on runs steps 2, 3 and 5 with standardised encodings (``encoders.standardise``, localize's
--standardise); both runs them plain and standardised side by side: step 2 once each a round (--rounds; the
order turned each round; wall time the rounds' median, peak RSS their max), step 3 two Localizers over the
same frames, blocks of ``BLOCK`` frames each, the order turned each block; then prints the ratios.
"""
from __future__ import annotations

import argparse
import csv
import os
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vpr_edge.encoders.standardise import STANDARDISE
from vpr_edge.errors import VprError
from vpr_edge.evaluation.metrics import answered_shares, transition_delays
from vpr_edge.evaluation.truth import load_csv
from vpr_edge.matchers import DEFAULT_MATCHER, MATCHERS, get_matcher
from vpr_edge.matchers.base import is_lost
from vpr_edge_bench.runner import parser, run_checked
from vpr_edge_bench.synthetic import plan_stream, write_route, write_stream
from vpr_edge_bench.yardstick import yardstick_ms

VARIANTS = {"off": (False,), "on": (True,), "both": (False, True)}   # --standardise: the Localizers compared
LABELS = {False: "plain", True: "standardised"}
BLOCK = 100   # frames one Localizer runs before the other takes its turn (--standardise both, step 3)


def status_mb(pid: int | str, field: str) -> float:
    """``field`` (RssAnon, RssFile, VmRSS) of process ``pid`` ("self") in MB; NaN when it has gone."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith(field + ":"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return float("nan")


def run_command(args: list[str]) -> dict:
    """Run ``python -m vpr_edge ARGS``: wall seconds, peak RSS (MB, from wait4) and RssAnon / RssFile sampled
    every 0.2 s (max, last). VprError with the command's last line of stderr if it fails."""
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "vpr_edge", *args], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    samples: list[tuple[float, float]] = []
    done = threading.Event()

    def sample() -> None:
        while not done.wait(0.2):
            anon, file = status_mb(proc.pid, "RssAnon"), status_mb(proc.pid, "RssFile")
            if anon == anon:
                samples.append((anon, file))

    watcher = threading.Thread(target=sample, daemon=True)
    watcher.start()
    err = proc.stderr.read() if proc.stderr else ""
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    wall = time.perf_counter() - t0
    done.set()
    watcher.join()
    if proc.returncode != 0:
        last = (err.strip().splitlines() or ["no message"])[-1]
        raise VprError(f"vpr-edge {' '.join(args[:1])} failed: {last}")
    anon = [a for a, _ in samples] or [float("nan")]
    file = [f for _, f in samples] or [float("nan")]
    return {"wall_s": wall, "peak_rss_mb": usage.ru_maxrss / 1024, "anon_max_mb": max(anon),
            "anon_last_mb": anon[-1], "file_max_mb": max(file)}


def per_frame(map_path: Path, queries: Path, checkpoints: list[int],
              standardise: Sequence[bool] = (False,), mode: str = DEFAULT_MATCHER) -> tuple[np.ndarray, list[tuple]]:
    """Each frame of ``queries`` through ``Localizer.push_encoding`` (one thread, matching with ``mode``), a
    Localizer for each of ``standardise`` (plain, standardised) taking turns ``BLOCK`` frames at a time, the
    order turned each block: (ms a frame (V, Q), [(frame, this process's RssAnon MB, RssFile MB) at each
    checkpoint])."""
    from vpr_edge.api import Localizer

    locs = [Localizer(map_path, threads=1, standardise=v, mode=mode) for v in standardise]
    q = np.load(queries, mmap_mode="r", allow_pickle=False)
    ms = np.empty((len(locs), len(q)))
    marks = []
    for lo in range(0, len(q), BLOCK):
        order = list(range(len(locs)))[::1 if lo // BLOCK % 2 == 0 else -1]
        for k in order:
            for t in range(lo, min(lo + BLOCK, len(q))):
                enc = np.asarray(q[t], np.float32)
                t0 = time.perf_counter()
                locs[k].push_encoding(enc)
                ms[k, t] = 1e3 * (time.perf_counter() - t0)
                if k == order[-1] and t + 1 in checkpoints:
                    marks.append((t + 1, status_mb("self", "RssAnon"), status_mb("self", "RssFile")))
    return ms, marks


def score(results: Path, truth_csv: Path, line: float | None, tolerance: int = 2) -> dict:
    """The localize output (every line with its best answer, ``--min-confidence 0``) against the ground truth
    (module docstring, step 5): a frame is lost below ``line`` (its score; None: as the output says)."""
    truth = load_csv(truth_csv)[:, 0]
    ref = np.full(len(truth), -10 ** 9, np.int64)
    lost = np.ones(len(truth), bool)
    with open(results, newline="") as f:
        for row in csv.DictReader(f):
            i = int(row["frame_index"])
            lost[i] = row["lost"] in ("1", "True", "true") if line is None else bool(is_lost(float(row["score"]), line))
            if row["ref_index"]:
                ref[i] = int(row["ref_index"])
    mapped = truth >= 0
    right = mapped & (np.abs(ref - truth) <= tolerance)
    answered_right, mapped_right = answered_shares(right, lost, mapped)
    relock, exits = transition_delays(mapped, right & ~lost, lost)
    return {"r_at_1": float(right[mapped].mean()), "answered_right": answered_right, "mapped_right": mapped_right,
            "offmap_lost": float(lost[~mapped].mean()) if (~mapped).any() else float("nan"),
            "exit_frames": exits.tolist(), "relock_frames": relock.tolist()}


def main(argv: Sequence[str] | None = None) -> int:
    p = parser(__name__, __doc__)
    p.add_argument("--work", type=Path, required=True, help="folder for the route, stream, map and output")
    p.add_argument("--places", type=int, default=1_000_000)
    p.add_argument("--frames", type=int, default=10_000)
    p.add_argument("--dim", type=int, default=512)
    p.add_argument("--noise", type=float, default=5.5, help="each frame's noise relative to a unit descriptor "
                   "(5.5: a frame alone right about 1 time in 4 on a million 512-dim places)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--checkpoints", default="1000,5000,10000,50000,100000")
    p.add_argument("--skip-build", action="store_true", help="use the map already in --work")
    p.add_argument("--mode", default=DEFAULT_MATCHER, help="the online matcher localize runs (localize --mode)")
    p.add_argument("--standardise", choices=tuple(VARIANTS), default="on" if STANDARDISE else "off",
                   help="standardised encodings (localize --standardise): off, on, or both side by side "
                        "(default: as localize)")
    p.add_argument("--rounds", type=int, default=1, help="localize commands of each variant (step 2)")
    a = p.parse_args(argv)
    return run_checked(__name__, lambda: _run(a))


def _run(a: argparse.Namespace) -> int:
    """The work of ``main``, its options checked first."""
    if a.places < 10 or a.frames < 100 or a.dim < 2 or not a.noise >= 0 or a.rounds < 1:
        raise VprError("need --places >= 10, --frames >= 100, --dim >= 2, --noise >= 0, --rounds >= 1")
    if a.mode not in MATCHERS or not get_matcher(a.mode).online:
        raise VprError(f"--mode {a.mode}: not an online matcher (one of "
                       f"{', '.join(m for m in MATCHERS if get_matcher(m).online)})")
    a.work.mkdir(parents=True, exist_ok=True)
    route = a.work / f"route_{a.places}x{a.dim}_s{a.seed}.npy"
    queries = a.work / f"stream_{a.places}x{a.dim}_{a.frames}_n{a.noise:g}_s{a.seed}.npy"
    truth = queries.with_suffix(".csv")
    map_path = route.with_suffix(".map.npz")
    if not route.exists():
        t0 = time.perf_counter()
        write_route(route, a.places, a.dim, seed=a.seed)
        print(f"route written in {time.perf_counter() - t0:.1f} s: {route}", file=sys.stderr)
    if not queries.exists() or not truth.exists():
        write_stream(route, plan_stream(a.places, a.frames, a.seed), queries, truth, noise=a.noise, seed=a.seed)
    rows: list[tuple[str, str, str]] = []
    if not (a.skip_build and map_path.exists()):
        built = run_command(["build-map", str(route), "-o", str(map_path)])
        rows += [("`build-map ROUTE.npy` (its index included), wall", f"{built['wall_s']:.1f} s", "<= 120 s"),
                 ("`build-map` peak RSS / RssAnon max",
                  f"{built['peak_rss_mb']:,.0f} MB / {built['anon_max_mb']:,.0f} MB "
                  f"(a {map_path.stat().st_size / 1e6:,.0f} MB map)", "bounded (never the float32 matrix)")]
    variants = VARIANTS[a.standardise]
    tag = "" if a.mode == DEFAULT_MATCHER else f".{a.mode}"
    outs = {v: queries.with_suffix(f"{tag}.std.results.csv" if v else f"{tag}.results.csv") for v in variants}
    runs: dict[bool, list[dict]] = {v: [] for v in variants}
    for r in range(a.rounds):
        for v in variants[::1 if r % 2 == 0 else -1]:
            cosines = "--standardise" if v else "--raw-cosines"
            runs[v].append(run_command(["localize", "--map", str(map_path), "--stream", str(queries), "--threads",
                                        "1", "-o", str(outs[v]), "--mode", a.mode, cosines, "--min-confidence", "0"]))
    checkpoints = sorted(int(c) for c in a.checkpoints.split(","))
    line = get_matcher(a.mode).lost_line(live=True)   # what localize reports lost below, by default
    ms, marks = per_frame(map_path, queries, checkpoints, variants, a.mode)
    yard = yardstick_ms()
    rows.append(("yardstick: one fp32 inference, 320x240, one thread", f"{yard:.2f} ms", ""))
    both = len(variants) > 1
    located = {}
    for k, v in enumerate(variants):
        located[v] = {"wall_s": float(np.median([x["wall_s"] for x in runs[v]]))} | \
            {key: max(x[key] for x in runs[v]) for key in ("peak_rss_mb", "anon_max_mb", "file_max_mb")} | \
            {"anon_last_mb": runs[v][-1]["anon_last_mb"]}
        rows += variant_rows(located[v], ms[k], score(outs[v], truth, line), yard, a.frames,
                             f" [{LABELS[v]}]" if both else "", a.rounds)
    rows.append(("RssAnon in process after " + " / ".join(f"{f:,}" for f, _, _ in marks) + " frames"
                 + (" (both Localizers)" if both else ""), " / ".join(f"{anon:.0f}" for _, anon, _ in marks) + " MB",
                 "flat"))
    if both:
        plain, std = located[False], located[True]
        rows += [
            ("standardised / plain: `localize` ms a frame (whole command); peak RSS; RssAnon max",
             f"{std['wall_s'] / plain['wall_s']:.3f}; {std['peak_rss_mb'] / plain['peak_rss_mb']:.3f}; "
             f"{std['anon_max_mb'] / plain['anon_max_mb']:.3f}", ""),
            ("standardised / plain: a frame's match (`push_encoding`), mean / p50 / p99",
             " / ".join(f"{f(ms[1]) / f(ms[0]):.3f}" for f in (np.mean, np.median, lambda x: np.percentile(x, 99))),
             "")]
    print(f"route of {a.places:,} places x {a.dim} dims, stream of {a.frames:,} frames, noise {a.noise:g}, "
          f"standardise {a.standardise}, mode {a.mode}\n")
    print("| | measured | target |\n|---|---|---|")
    for what, measured, target in rows:
        print(f"| {what} | {measured} | {target} |")
    return 0



def variant_rows(located: dict, ms: np.ndarray, s: dict, yard: float, frames: int, label: str,
                 rounds: int) -> list[tuple[str, str, str]]:
    """The table's rows of one variant (plain or standardised, named by ``label``): its localize command
    (``run_command``'s figures; wall the median of ``rounds``), its frames' match ms (Q,) and its scores
    (``score``), times beside the yardstick's ``yard`` ms."""
    cmd_ms = 1e3 * located["wall_s"] / frames
    p50, p99, top = np.percentile(ms, 50), np.percentile(ms, 99), ms.max()
    warm = ms[10:].max() if len(ms) > 10 else float("nan")   # past the first reads of a cold page cache
    median = f", median of {rounds}" if rounds > 1 else ""
    return [
        (f"`localize --threads 1` over the {frames:,} frames, whole command (start-up included){median}{label}",
         f"{located['wall_s']:.1f} s: {cmd_ms:.2f} ms a frame, {cmd_ms / yard:.2f}x the yardstick", "<= 0.35x"),
        (f"`localize` RssAnon max / last; RssFile max (sampled every 0.2 s); peak RSS{label}",
         f"{located['anon_max_mb']:.0f} / {located['anon_last_mb']:.0f} MB; {located['file_max_mb']:.0f} MB; "
         f"{located['peak_rss_mb']:,.0f} MB", "RssAnon <= 250 MB"),
        (f"a frame's match (`push_encoding`), mean / p50 / p99 / max; max after the first 10 frames{label}",
         f"{ms.mean():.2f} / {p50:.2f} / {p99:.2f} / {top:.1f} ms (frame {int(ms.argmax())}: {top / yard:.2f}x the "
         f"yardstick); {warm:.1f} ms ({warm / yard:.2f}x)", "no frame over 3x"),
        (f"R@1 +-2 over mapped frames; answers given right; mapped frames answered right{label}",
         f"{s['r_at_1']:.3f}; {s['answered_right']:.3f}; {s['mapped_right']:.3f}", ">= 0.95"),
        (f"off-map frames reported lost; first lost frame after leaving{label}",
         f"{s['offmap_lost']:.3f}; " + " and ".join(f"{x:.0f}" for x in s["exit_frames"]) + " frames", ">= 0.90"),
        (f"first right answer after the cold start / each re-entry{label}",
         " / ".join(f"{x:.0f}" for x in s["relock_frames"]) + " frames", "re-lock <= 10"),
    ]
