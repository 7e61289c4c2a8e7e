"""SIGKILL at random moments: every map, log and recording survives (slow: about a second a kill).

Each writer of a file is killed ``KILLS_PER_KIND`` times at a random moment of its run: ``build-map`` (a new
map, over an old one, ``--append``), ``localize`` with each output kind (CSV, JSON lines, MCAP, a Rerun
recording) and ``evaluate --save-calibration``. After each kill: a map loads and is the old one or the whole
new one; a calibration file is absent, the old one or a whole new one; a log's lines are whole (the last one
may be cut short in ``NAME.part``, which the next run cuts); a recording's part reads back with its own
reader, and ``NAME`` (a killed run's part the next run finalised) reads whole. The next run to each output
recovers what the killed one left, and a last run that ends leaves nothing stray (no ``.part``, ``.tmp`` or
lock file)."""
from __future__ import annotations

import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from helpers import mcap_answer_frames

from vpr_edge.files.temps import dead_writers_files
from vpr_edge.map import load_map
from vpr_edge.resources import sample_folder

pytestmark = pytest.mark.slow

CLI = [sys.executable, "-m", "vpr_edge"]
KILLS_PER_KIND = int(os.environ.get("VPR_EDGE_KILLS", 25))   # eight kinds: 200 kills


@pytest.fixture(scope="module")
def ws(tmp_path_factory: pytest.TempPathFactory, small_refs: Path, small_queries: Path) -> Path:
    """Half the small references and all of them, an old map of the half, a long stream, ground truth."""
    w = tmp_path_factory.mktemp("kills")
    refs = sorted(small_refs.iterdir())
    (w / "half").mkdir()
    for f in refs[:12]:
        shutil.copy(f, w / "half" / f.name)
    (w / "rest").mkdir()
    for f in refs[12:]:
        shutil.copy(f, w / "rest" / f.name)
    proc = subprocess.run([*CLI, "build-map", w / "half", "-o", w / "old.npz", "--components", "4"],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    (w / "long").mkdir()
    for k in range(2):
        for f in sorted((sample_folder() / "query").glob("*.jpg")):
            (w / "long" / f"{k}{f.name}").symlink_to(f)
    shutil.copytree(small_queries, w / "queries")
    with open(w / "gt.csv", "w") as f:
        f.write("query,references\n")
        for i, q in enumerate(sorted(small_queries.iterdir())):
            f.write(f"{i},{' '.join(str(r) for r in range(max(0, i - 2), min(12, i + 3)))}\n")
    return w


def _kill_at_random(args: list, rng: random.Random, life_s: float) -> bool:
    """Run ``vpr-edge ARGS`` and SIGKILL it at a random moment of its ``life_s``; True if the kill came before
    it ended."""
    proc = subprocess.Popen([*CLI, *map(str, args)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        proc.wait(timeout=rng.uniform(0.05, 0.95 * life_s))
        return False
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=60)
        return True


def _names(path: Path) -> int:
    return len(load_map(path).names)


def _whole_lines(path: Path, last_may_be_cut: bool) -> None:
    if not path.exists():
        return
    data = path.read_bytes()
    lines = data.split(b"\n")
    if not last_may_be_cut:
        assert data.endswith(b"\n") or not data, path
    for line in lines[:-1]:
        if path.name.startswith("run.jsonl"):
            json.loads(line)
        else:
            assert line.count(b",") == data.split(b"\n", 1)[0].count(b","), (path, line)


def _readable_recording(part: Path) -> None:
    if not part.exists():
        return
    if part.name.startswith("run.mcap"):
        frames = mcap_answer_frames(part)
        assert frames == list(range(len(frames))), part
    else:
        from rerun.chunk import RrdReader

        try:
            reader = RrdReader(part)
        except RuntimeError as e:            # killed before its first record: nothing written yet
            assert "too small" in str(e), e
            return
        for _ in reader.stream():            # reads to where the kill cut it, without an error
            pass


def _whole_recording(out: Path) -> None:
    """``NAME``, when there, reads back whole with its own reader: an MCAP file with its summary (a killed
    run's part finalised by the next run), a recording to its end."""
    if not out.exists():
        return
    if out.suffix == ".mcap":
        from mcap.reader import make_reader

        with open(out, "rb") as f:
            reader = make_reader(f)
            assert reader.get_summary() is not None, out
            frames = [json.loads(m.data)["frame_index"] for _, c, m in reader.iter_messages()
                      if c.topic == "/vpr/answer"]
        assert frames == list(range(len(frames))) and frames, out
    else:
        from rerun.chunk import RrdReader

        assert sum(1 for _ in RrdReader(out).stream()) > 0, out


OUTS = {"build-new": "m.npz", "build-over": "m.npz", "build-append": "m.npz", "evaluate": "cal.json",
        "csv": "run.csv", "jsonl": "run.jsonl", "mcap": "run.mcap", "rrd": "run.rrd"}


def _args(ws: Path, kind: str, out: Path) -> list:
    """The command of ``kind`` writing ``out``; a map to build over or append to is put there first."""
    if kind in ("build-over", "build-append"):
        shutil.copy(ws / "old.npz", out)
    elif kind == "build-new":
        out.unlink(missing_ok=True)
    if kind == "build-new":
        return ["build-map", ws / "half", "-o", out, "--components", "4"]
    if kind == "build-over":
        return ["build-map", ws / "half", ws / "rest", "-o", out, "--components", "4"]
    if kind == "build-append":
        return ["build-map", ws / "rest", "--append", "-o", out]
    if kind == "evaluate":
        return ["evaluate", "--map", ws / "old.npz", "--queries", ws / "queries", "--gt", ws / "gt.csv",
                "--modes", "single", "--save-calibration", out]
    return ["localize", "-m", ws / "old.npz", "-s", ws / "long", *(["--rerun", out] if kind == "rrd" else
                                                                   ["-o", out])]


def _check(kind: str, out: Path) -> None:
    """What a kill of ``kind`` may leave of ``out``."""
    if kind == "build-new":
        assert not out.exists() or _names(out) == 12
    elif kind.startswith("build"):
        assert _names(out) in (12, 24)
    elif kind == "evaluate":
        assert not out.exists() or isinstance(json.loads(out.read_text()), dict)   # whole, or none
    elif kind in ("csv", "jsonl"):
        _whole_lines(out, last_may_be_cut=False)
        _whole_lines(Path(f"{out}.part"), last_may_be_cut=True)
    else:
        _readable_recording(Path(f"{out}.part"))
        _whole_recording(out)


def _kind(ws: Path, kind: str, seed: int) -> tuple[int, int]:
    """``KILLS_PER_KIND`` kills of one kind in a folder of its own, each checked; a run to its end before
    (how long a run lives: the kills fall inside it) and after (it recovers what the last kill left). Returns
    (kills, runs: a run may end before its kill)."""
    rng = random.Random(seed)
    d = ws / kind
    d.mkdir()
    out = d / OUTS[kind]
    life = _clean_run(_args(ws, kind, out), d)
    killed = runs = 0
    while killed < KILLS_PER_KIND and runs < 3 * KILLS_PER_KIND:
        runs += 1
        killed += _kill_at_random(_args(ws, kind, out), rng, life)
        _check(kind, out)
    _clean_run(_args(ws, kind, out), d)
    return killed, runs


def _clean_run(args: list, d: Path) -> float:
    """``vpr-edge ARGS`` to its end, writing into ``d``: nothing stray is left; its wall time, seconds."""
    t0 = time.perf_counter()
    proc = subprocess.run([*CLI, *map(str, args)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    stray = [p.name for p in d.iterdir() if p.name.endswith((".part", ".tmp", ".lock"))]
    assert not stray and not dead_writers_files(d / "m.npz"), stray
    return time.perf_counter() - t0


def test_two_hundred_kills_lose_nothing(ws: Path) -> None:
    pytest.importorskip("mcap")
    pytest.importorskip("rerun")
    kinds = ["build-new", "build-over", "build-append", "csv", "jsonl", "mcap", "rrd", "evaluate"]
    t0 = time.perf_counter()
    with ThreadPoolExecutor(2) as pool:                     # two at a time: CI's two cores
        done = list(pool.map(lambda k: _kind(ws, *k), [(k, i) for i, k in enumerate(kinds)]))
    killed, runs = sum(k for k, _ in done), sum(n for _, n in done)
    assert killed == 8 * KILLS_PER_KIND, (dict(zip(kinds, done)), round(time.perf_counter() - t0))
