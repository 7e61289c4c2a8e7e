"""The experiments of the development package (``python -m vpr_edge_bench NAME``) run and print what they
promise (small sizes; no timing is asserted)."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from vpr_edge_bench.streams import KINDS

ROOT = Path(__file__).resolve().parent.parent
NOT_STREAMS = "not a derived-streams folder with its map (no map.npz; make one: python -m vpr_edge_bench derive-streams"


def bench_run(*args: str, timeout: int = 600) -> subprocess.CompletedProcess:
    """``python -m vpr_edge_bench ARGS`` from anywhere (the checkout on PYTHONPATH, as at its root)."""
    env = os.environ | {"PYTHONPATH": os.pathsep.join([str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])}
    return subprocess.run([sys.executable, "-m", "vpr_edge_bench", *args], capture_output=True, text=True,
                          timeout=timeout, env=env)


def tool(name: str, *args: str) -> str:
    """The experiment ``name``'s stdout (it must succeed)."""
    proc = bench_run(name, *args)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout


def derived(tmp_path: Path, refs: Path, queries: Path, kinds: str) -> tuple[Path, Path]:
    """A dataset folder (ref/, query/) of the given frames and its derived streams ``kinds`` (all 24 mapped)."""
    import shutil

    data = tmp_path / "pair"
    shutil.copytree(refs, data / "ref")
    shutil.copytree(queries, data / "query")
    streams = tmp_path / "streams"
    tool("derive-streams", "--dataset", str(data), "--out", str(streams), "--kinds", kinds, "--map-places", "24")
    return data, streams


@pytest.mark.slow
@pytest.mark.parametrize("mapped", [False, True])
def test_bench_matcher_reports_each_checkpoint(mapped: bool, tmp_path: Path) -> None:
    # without a motion cue the filter follows a stopping vehicle poorly (docs/results.md): stream-rules there
    extra = ["--mmap", str(tmp_path / "refs.npz"), "--coarse", "--cue"] if mapped else ["--matcher", "stream-rules"]
    out = tool("bench-matcher", "--refs", "300", "--frames", "2000", "--dim", "32", "--checkpoints",
               "500,2000", "--storage", "int8", "--window", "20", *extra)
    rows = [line.split() for line in out.splitlines() if line.split() and line.split()[0].isdigit()]
    assert [r[0] for r in rows] == ["500", "2000"]
    assert all(float(r[-2]) > 0.8 for r in rows)          # synthetic route is followed
    assert all(float(r[-1]) > 0.3 for r in rows)          # mostly by the local search
    assert all(float(r[4]) > 0 and float(r[5]) > 0 and float(r[7]) > 0 for r in rows)   # RSS columns filled
    assert ("memory-mapped from" in out) == mapped and (tmp_path / "refs.npz").is_file() == mapped
    assert f"motion cue {'on' if mapped else 'off'}" in out


def test_bench_scale_builds_localizes_and_scores(tmp_path: Path) -> None:
    out = tool("bench-scale", "--work", str(tmp_path), "--places", "3000", "--frames", "300", "--dim", "32",
               "--noise", "0.7", "--checkpoints", "100,300")
    rows = {r.split(" | ")[0].strip("| "): r.split(" | ")[1] for r in out.splitlines() if r.startswith("| ")}
    assert "x the yardstick" in rows["a frame's match (`push_encoding`), mean / p50 / p99 / max; max after the "
                                     "first 10 frames"]
    assert any(k.startswith("`build-map ROUTE.npy`") for k in rows)
    assert rows["RssAnon in process after 100 / 300 frames"].endswith(" MB")
    r_at_1 = float(rows["R@1 +-2 over mapped frames; answers given right; mapped frames answered right"].split(";")[0])
    lost = float(rows["off-map frames reported lost; first lost frame after leaving"].split(";")[0])
    assert r_at_1 > 0.5 and lost > 0.5                       # the hard stream is followed, its detours lost


@pytest.mark.parametrize("name, args, needle", [
    ("lost-tradeoff", ["--streams", "{tmp}", "--locks", "x"], "--locks 'x': want positive numbers"),
    ("lost-tradeoff", ["--streams", "{tmp}", "--locks", "0,6"], "--locks '0,6': want positive numbers"),
    ("lost-tradeoff", ["--streams", "{tmp}", "--param", "nope=1"], "--param 'nope=1': stream-rules takes KEY=VALUE"),
    ("lost-tradeoff", ["--streams", "{tmp}"], NOT_STREAMS),
    ("lost-tradeoff", ["--streams", "{tmp}", "--vary", "nope"], "--vary 'nope': not a numeric stream parameter"),
    ("lost-tradeoff", ["--streams", "{tmp}", "--vary", "still_memory", "--values", "10.5"],
     "still_memory takes whole numbers"),
    ("lost-tradeoff", ["--streams", "{tmp}", "--vary", "evidence_decay", "--values", "2"],
     "evidence_decay must be in [0, 1)"),
    ("lost-tradeoff", ["--streams", "{tmp}", "--vary", "still_memory", "--values", "10", "--against", "1.5"],
     "--against 1.5: want a whole number"),
    ("results", ["--datasets", "{tmp}", "--out", "{tmp}/out", "--quick"], "not a dataset folder with ref/"),
    ("results", ["--datasets", "{tmp}", "--out", "{tmp}/out", "--sections", "nope"], "no section 'nope'"),
    ("bench-matcher", ["--stop-noise", "-1"], "--stop-noise must be >= 0"),
    ("bench-matcher", ["--param", "peaks=maybe"], "'maybe' is not an int"),
    ("bench-scale", ["--work", "{tmp}", "--places", "5"], "need --places >= 10"),
    ("calibration-check", ["--streams", "{tmp}", "{tmp}", "--fits", "logistic,nope"],
     "--fits 'logistic,nope': choose from logistic, isotonic"),
    ("calibration-check", ["--streams", "{tmp}", "{tmp}", "--modes", "nope"], "--modes: unknown matcher 'nope'"),
    ("calibration-check", ["--streams", "{tmp}", "{tmp}"], NOT_STREAMS),
    ("compare-front-ends", ["--streams", "{tmp}", "--front", "gem"], "--front gem: expected NAME=MODEL"),
    ("compare-front-ends", ["--streams", "{tmp}", "--front", "gem={tmp}/no.onnx"], "model file not found"),
    ("compare-front-ends", ["--streams", "{tmp}", "--front", "default"], "not a derived-streams folder (no ref"),
    ("compare-drives", ["--streams", "{tmp}"], "not a derived-streams folder (no ref"),
    ("bench-fleet", ["--refs", "{tmp}/none"], "none: not a folder"),
    ("bench-e2e", ["--streams", "{tmp}", "--config", "d="], "not a derived-streams folder (no ref"),
    ("size-sweep", ["--streams", "{tmp}", "--out", "{tmp}/out"], "not a derived-streams folder (no ref"),
    ("coarse-check", ["--map", "{tmp}/m.npz", "--streams", "{tmp}"], "not a derived-streams folder (no aligned"),
    ("front-end-cache", ["--streams", "{tmp}", "--out", "{tmp}/out"], "not a derived-streams folder (no ref"),
    ("front-end-cache", ["--streams", "{tmp}/a", "{tmp}/b/a", "--out", "{tmp}/out"], "names name the datasets"),
    ("front-end-lines", ["--cache", "{tmp}/none"], "none: not a folder"),
    ("probability-targets", ["--cache", "{tmp}/none"], "none: not a folder"),
    ("probability-targets", ["--cache", "{tmp}", "--modes", "nope"], "--modes: unknown matcher 'nope'"),
    ("probability-targets", ["--cache", "{tmp}", "--target-precision", "1"], "must lie in (0, 1)"),
    ("front-end-lines", ["--cache", "{tmp}", "--modes", "stream,stream:peaks=maybe"], "'maybe' is not an int"),
    ("front-end-lines", ["--cache", "{tmp}", "--modes", "stream:nope=1"], "stream takes KEY=VALUE with KEY one of"),
    ("front-end-lines", ["--cache", "{tmp}", "--frames", "drop:2"], "--frames must be one of as-recorded, twice"),
    ("one-view-check", ["--streams", "{tmp}"], NOT_STREAMS),
    ("eval-streams", ["--streams", "{tmp}"], NOT_STREAMS),
    ("eval-streams", ["--streams", "{tmp}", "--modes", "stream,nope"], "--modes 'stream,nope': unknown nope"),
    ("eval-streams", ["--streams", "{tmp}", "--fronts", "nope"], "--fronts 'nope': choose from map, pixels"),
    ("leave-one-out", ["--streams", "{tmp}", "{tmp}"], "names name the datasets and must differ"),
    ("lost-reasons", ["--streams", "{tmp}"], NOT_STREAMS),
    ("lost-reasons", ["--streams", "{tmp}", "--tolerance", "-1"], "--tolerance must be >= 0"),
    ("leave-one-out", ["--streams", "{tmp}/a", "{tmp}/b"], NOT_STREAMS),
])
def test_experiments_refuse_bad_input_in_one_line(tmp_path: Path, name: str, args: list[str], needle: str) -> None:
    """One line on stderr naming the problem, exit 2, before any work (nothing written)."""
    proc = bench_run(name, *[x.format(tmp=tmp_path) for x in args], timeout=120)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr
    assert lines[0].startswith(f"{name}: error: ") and needle in lines[0]
    assert proc.stdout == "" and list(tmp_path.iterdir()) == []


def test_front_end_lines_checks_every_labelled_drive_first(tmp_path: Path) -> None:
    """--calibrate-on names a stream every cached front end must hold: one line naming the missing file,
    exit 2, before any output."""
    for front in ("hog", "ifv"):
        (tmp_path / "corridor" / front).mkdir(parents=True)
    np.savez(tmp_path / "corridor" / "hog" / "aligned.npz", sim=np.zeros((2, 2)))
    proc = bench_run("front-end-lines", "--cache", str(tmp_path), "--calibrate-on", "aligned", timeout=120)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and proc.stdout == "", proc.stderr
    assert "ifv/aligned.npz: no such stream to calibrate on (--calibrate-on)" in lines[0]

@pytest.mark.slow
def test_thesis_grid_writes_tables_and_curves(tmp_path: Path, small_refs: Path, small_queries: Path) -> None:
    import json

    data, streams = derived(tmp_path, small_refs, small_queries, "speed2")
    out = tmp_path / "grid"
    text = tool("thesis-grid", "--dataset", str(data), "--stream", str(streams / "speed2"), "--out", str(out),
                "--groups", "handcrafted,encodings", "--components", "4")
    assert (out / "grid.md").read_text().strip() == text.strip()
    rows = json.loads((out / "grid.json").read_text())
    configs = {(r["front_end"], r["encoding"], r["mode"], r["queries"]) for r in rows}
    assert ("ldb", "none", "dtw", "speed2") in configs and ("hog", "none", "single", "aligned") in configs
    assert {e for f, e, m, q in configs if m == "svm"} == {"none", "bow", "vlad", "fv", "ifv"}
    assert all(0 <= r["auc"] <= 1 and 0 <= r["ap"] <= 1 for r in rows)
    assert "| sift + none | dtw |" in text and "thesis" in text
    assert {p.name for p in out.glob("*.png")} == {f"{g}.{q}.pr.png" for g in ("handcrafted", "encodings")
                                                   for q in ("aligned", "speed2")}


@pytest.mark.slow
def test_bench_frame_reports_each_stage(tmp_path: Path, small_refs: Path, small_queries: Path) -> None:
    m = tmp_path / "m.npz"
    build = subprocess.run([sys.executable, "-m", "vpr_edge", "build-map", str(small_refs), "-o", str(m),
                            "--components", "2"], capture_output=True, text=True, timeout=600)
    assert build.returncode == 0, build.stderr
    out = tool("bench-frame", "--map", str(m), "--frames", str(small_queries), "--threads", "1", "--repeat", "1")
    row = out.splitlines()[-1].split()
    assert row[0] == "1" and len(row) == 6 and all(float(v) > 0 for v in row[1:])
    assert abs(sum(float(v) for v in row[1:5]) - float(row[5])) <= 0.025 + 1e-9   # stages add up (5 values to 0.01)


@pytest.mark.slow
def test_size_sweep_reports_each_configuration(tmp_path: Path, small_refs: Path, small_queries: Path) -> None:
    streams = tmp_path / "streams"
    streams.mkdir()
    (streams / "ref").symlink_to(small_refs)
    (streams / "aligned").symlink_to(small_queries)
    n = len(list(small_queries.iterdir()))
    (streams / "aligned.csv").write_text("query,references\n" + "".join(f"{i},{i}\n" for i in range(n)))
    out = tool("size-sweep", "--streams", str(streams), "--kinds", "aligned", "--configs", "0x4,8x2",
               "--storages", "int8,bits", "--modes", "single", "--out", str(tmp_path / "out"), "--threads", "1")
    table, means = out.split("Means over the seeds and streams")
    rows = [line.split("|")[1:-1] for line in table.splitlines() if line.startswith("| ") and "PCA" not in line]
    assert [(r[0].strip(), r[1].strip(), r[4].strip()) for r in rows] == [
        ("none", "4", "int8"), ("none", "4", "bits"), ("8", "2", "int8"), ("8", "2", "bits")]
    assert [r[6].strip() for r in rows] == ["900", "112", "36", "4"]      # bytes per place: D + 4, D / 8
    assert {r[2].strip() for r in rows} == {"30000x20"}                    # build-map's fit
    r1 = [float(r[-1].split("/")[0]) for r in rows]
    assert min(r1[:2]) >= 0.7 and all(0.0 <= v <= 1.0 for v in r1)      # the sample's queries are found
    assert r1[0] > r1[2]                                                   # 896 dims beat 32
    mean_rows = [line.split("|")[1:-1] for line in means.splitlines() if line.startswith("| ") and "PCA" not in line]
    assert [float(r[-1].split("/")[0]) for r in mean_rows] == r1            # one seed, one stream: the rows
    assert (tmp_path / "out" / "size.json").exists() and (tmp_path / "out" / "local" / "ref" / "local.npy").exists()


@pytest.mark.slow
def test_coarse_check_compares_exact_and_coarse(tmp_path: Path, small_refs: Path, small_queries: Path) -> None:
    m = tmp_path / "m.npz"
    build = subprocess.run([sys.executable, "-m", "vpr_edge", "build-map", str(small_refs), "-o", str(m),
                            "--components", "4"], capture_output=True, text=True, timeout=600)
    assert build.returncode == 0, build.stderr
    streams = tmp_path / "streams"
    streams.mkdir()
    (streams / "aligned").symlink_to(small_queries)
    n = len(list(small_queries.iterdir()))
    (streams / "aligned.csv").write_text("query,references\n" + "".join(f"{i},{i}\n" for i in range(n)))
    out = tool("coarse-check", "--map", str(m), "--streams", str(streams), "--kinds", "aligned", "--keep", "24",
               "--threads", "1")
    row = [c.strip() for c in out.splitlines()[-1].split("|")[1:-1]]
    assert row[0] == "aligned" and row[1] == row[2]      # keep >= R: every value exact, the same answers
    assert row[3] == row[4]
    assert row[5] == "1.000" and row[6] == "1.00"        # 24 places: no local search, every frame whole-route


@pytest.mark.parametrize("args, needle", [
    (["--kinds", "speed2,warp"], "--kinds: unknown warp"),
    (["--repeat-noise", "-1"], "--repeat-noise must be >= 0"),
    (["--map-places", "999"], "--map-places must be in 1..24"),
    (["--drives", "25"], "--drives must be in 1..16"),
])
@pytest.mark.slow
def test_derive_streams_checks_before_writing(tmp_path: Path, small_refs: Path, small_queries: Path,
                                              args: list[str], needle: str) -> None:
    import shutil

    data = tmp_path / "pair"
    shutil.copytree(small_refs, data / "ref")
    shutil.copytree(small_queries, data / "query")
    proc = bench_run("derive-streams", "--dataset", str(data), "--out", str(tmp_path / "streams"), *args)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr
    assert lines[0].startswith("derive-streams: error: ") and needle in lines[0]
    assert not (tmp_path / "streams").exists()                  # nothing written


@pytest.mark.slow
def test_bench_e2e_and_calibration_check(tmp_path: Path, small_refs: Path, small_queries: Path) -> None:
    """bench_e2e: a row per configuration with accuracy, per-frame time beside the yardstick, bytes a place
    and build time; calibration_check: the ECE table for a calibration fitted on each of two datasets."""
    import json
    import shutil

    _, streams = derived(tmp_path, small_refs, small_queries, "aligned,speed2")
    text = tool("bench-e2e", "--streams", str(streams), "--kinds", "aligned,speed2", "--config",
                "small=--components 4", "--config", "small-int8=--components 4|--precision int8")
    doc = json.loads((streams / "bench" / "bench.json").read_text())
    assert len(doc["yardstick_ms"]) == 2 and all(y > 0 for y in doc["yardstick_ms"])
    rows = {r["config"]: r for r in doc["rows"]}
    assert rows["small"]["bytes_per_place"] == 2 * 4 * 24 + 4 and rows["small"]["form"] == "fp32: asked for"
    assert rows["small-int8"]["model"].endswith(".int8.onnx")
    for r in rows.values():
        assert r["build_s"] > 0 and r["startup_s"] > 0
        assert all(0 <= s["r1"] <= 1 and s["wall_ms"] > 0 for s in r["streams"].values())
    assert "| small | efficientnet_lite0_stage5_160x120.onnx (fp32) |" in text
    # two "datasets": the same streams under two names (each with the map), so either calibration fits the
    # other exactly as its own
    for name in ("one", "two"):
        shutil.copytree(streams, tmp_path / name, ignore=shutil.ignore_patterns("bench"))
        shutil.copy(streams / "bench" / "small.npz", tmp_path / name / "map.npz")
        for kind in KINDS:
            src = streams / ("speed2" if kind == "speed2" else "aligned")
            if kind not in ("aligned", "speed2"):
                shutil.copytree(src, tmp_path / name / kind)
                shutil.copy(streams / f"{src.name}.csv", tmp_path / name / f"{kind}.csv")
    text = tool("calibration-check", "--streams", str(tmp_path / "one"), str(tmp_path / "two"), "--modes",
                "stream", "--fits", "logistic,isotonic", "--write", str(tmp_path / "cal"))
    assert "stream, tolerance 2, logistic fit" in text and "stream, tolerance 2, isotonic fit" in text
    rows = [line.split("|") for line in text.splitlines() if line.startswith("| one") or line.startswith("| two")]
    ece = slice(3, 3 + len(KINDS) + 4)   # per stream, all, other frames, Brier, a constant's
    assert len(rows) == 8 and all(r[ece] == r2[ece] for r, r2 in zip(rows[::2], rows[1::2]))   # same ECEs
    assert json.loads((tmp_path / "cal" / "one.json").read_text())["kind"] == "calibration"
    text = tool("lost-tradeoff", "--streams", str(tmp_path / "one"), "--locks", "5,6")
    rows = [line.split("|")[1:-1] for line in text.splitlines() if line.startswith("| one")]
    assert [r[1].strip() for r in rows] == ["5", "6"]
    for r in rows:   # no unmapped frames here: nothing to lose, nothing to exit
        assert r[2].strip() == "nan" and r[3].strip() == "-" and 0 <= float(r[6].split()[0]) <= 1
    # the same streams under two names: each dataset's choice is the other's, so held out scores as its own
    text = tool("leave-one-out", "--streams", str(tmp_path / "one"), str(tmp_path / "two"))
    choices = [line.split("|")[1:-1] for line in text.splitlines() if line.startswith("| `")]
    assert [c[0].strip() for c in choices] == ["`still`", "`lock`", "`evidence`", "`unique`", "`confirm`"]
    assert all(c[3] == c[4] and float(c[3]) in [float(v) for v in c[1].split(",")] for c in choices)
    rows = {tuple(c.strip() for c in line.split("|")[1:4]): line.split("|")[4:-1]
            for line in text.splitlines() if line.startswith("| one") or line.startswith("| two")}
    assert len(rows) == 12
    for ds, other in (("one", "two"), ("two", "one")):
        for frames in ("all", "away from one view"):
            held = rows[ds, f"chosen on {other} (held out)", frames]
            assert held == rows[ds, f"chosen on {ds} (own)", frames]
            shares = [float(x) for cell in held[:len(KINDS)] for x in cell.split("/")]   # NaN: nothing answered
            assert all(0 <= x <= 1 or np.isnan(x) for x in shares) and not np.isnan(shares[1])
    text = tool("lost-reasons", "--streams", str(tmp_path / "one"))   # every lost frame has its reason
    rows = [line.split("|")[1:-1] for line in text.splitlines() if line.startswith("| one")]
    assert [r[1].strip() for r in rows] == list(KINDS)
    for r in rows:
        n, unmapped, mapped = (int(c) for c in r[2:5])
        assert n == unmapped + mapped and unmapped == 0 and all(c.strip().startswith("0 / ") for c in r[5:])
    text = tool("one-view-check", "--streams", str(tmp_path / "one"))
    assert "agrees with the map's motion cue on" in text
    rows = [line.split("|")[1:-1] for line in text.splitlines() if line.startswith("| aligned")]
    given, wrong, at_run = (int(c) for c in rows[0][1:])
    assert len(rows) == 1 and 0 <= at_run <= wrong <= given <= 24


@pytest.mark.slow
def test_results_quick_measures_every_stream(tmp_path: Path, small_refs: Path, small_queries: Path) -> None:
    """results --quick on two tiny datasets (the sample's first 24 frames under both names): every
    derived stream scored for both matchers at both tolerances, the speed ratio, the commit and the machine."""
    import json
    import shutil

    for name in ("corridor", "nordland-dev"):
        shutil.copytree(small_refs, tmp_path / "data" / name / "ref")
        shutil.copytree(small_queries, tmp_path / "data" / name / "query")
    out = tool("results", "--datasets", str(tmp_path / "data"), "--out", str(tmp_path / "out"), "--quick")
    doc = json.loads((tmp_path / "out" / "results.json").read_text())
    assert set(doc["datasets"]) == {"corridor", "nordland-dev"} and doc["machine"]["cores"] >= 1
    for data in doc["datasets"].values():
        assert set(data["streams"]) == set(KINDS)
        for modes in data["streams"].values():
            assert set(modes) == {"stream", "seqslam-online"} and all(set(t) == {"2", "1"} for t in modes.values())
            assert all(0 <= t["2"]["r1"] <= 1 and t["1"]["r1"] <= t["2"]["r1"] for t in modes.values())
    assert all(doc["speed"][n]["x_yardstick"] > 0 for n in doc["datasets"])
    assert "| aligned |" in out and "yardstick" in out


@pytest.mark.slow
def test_compare_front_ends_reports_each_front_end(tmp_path: Path, small_refs: Path, small_queries: Path) -> None:
    """compare-front-ends on the sample's first 24 frames: the default and a GeM global model, each
    stream's cells and the bytes a place / ms a frame lines."""
    pytest.importorskip("torch")
    from vpr_edge_bench.streams import derive_streams
    from vpr_edge_export.onnx_export import default_weights, export_global

    (tmp_path / "data").mkdir()
    shutil.copytree(small_refs, tmp_path / "data" / "ref")
    shutil.copytree(small_queries, tmp_path / "data" / "query")
    derive_streams(tmp_path / "data", tmp_path / "ds")
    gem = tmp_path / "gem.onnx"
    export_global("gem", default_weights("efficientnet_lite0"), 160, 120, gem, backbone="efficientnet_lite0",
                  tap="stage5")
    out = tool("compare-front-ends", "--streams", str(tmp_path / "ds"), "--front", "default", "--front",
               f"gem={gem}")
    assert "| default |" in out and "| gem |" in out
    assert "gem: 116 bytes a place" in out and "x the yardstick" in out
    assert (tmp_path / "ds" / "map.gem.npz").is_file()


def test_every_results_section_has_its_markers_in_one_document() -> None:
    """Each section of the results experiment has its markers, once, in one document of docs/, and every
    marker there is a section's; each section is made by a registered experiment."""
    import re

    from vpr_edge_bench.experiments.results import SECTIONS, section_markers
    from vpr_edge_bench.runner import experiments

    text = "\n".join(p.read_text() for p in sorted((ROOT / "docs").glob("*.md")))
    names = [s.name for s in SECTIONS]
    assert len(set(names)) == len(names)
    assert set(re.findall(r"^<!-- generated: ([\w-]+) -->$", text, re.MULTILINE)) == set(names)
    for name in names:
        start, end = section_markers(name)
        assert text.count(start) == text.count(end) == 1
    assert {s.experiment for s in SECTIONS} <= set(experiments())   # each made by a registered experiment


def test_the_runner_lists_every_experiment_in_one_line_each() -> None:
    """``python -m vpr_edge_bench`` alone: usage, then each module of ``experiments`` as NAME and its summary
    on one line; an unknown name is one line on stderr and exit code 2."""
    from vpr_edge_bench.runner import experiments

    proc = bench_run()
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    modules = sorted(p.stem.replace("_", "-") for p in (ROOT / "vpr_edge_bench" / "experiments").glob("[a-z]*.py"))
    listed = [line.split()[0] for line in proc.stdout.splitlines() if line.startswith("  ")]
    assert listed == modules == list(experiments()) and "front-end-cache" in listed
    for name, summary in experiments().items():
        assert summary and f"  {name}  " in proc.stdout and proc.stdout.count(summary) == 1
    proc = bench_run("nope")
    assert proc.returncode == 2 and proc.stdout == "" and len(proc.stderr.strip().splitlines()) == 1
    assert proc.stderr.startswith("vpr_edge_bench: error: no experiment 'nope'")


def test_every_experiment_is_run_by_a_test_or_named_in_a_document() -> None:
    """No experiment without a test that runs it (``tool("NAME"``, ``bench_run("NAME"``, a bad-input case, or
    ``"vpr_edge_bench", "NAME"`` in a command line) or a document that names its command (``python -m
    vpr_edge_bench NAME``)."""
    import re

    from vpr_edge_bench.runner import experiments

    docs = "\n".join(p.read_text() for p in [ROOT / "README.md", *(ROOT / "docs").glob("*.md")])
    tests = "\n".join(p.read_text() for p in (ROOT / "tests").glob("test_*.py"))
    unused = [n for n in experiments() if f"python -m vpr_edge_bench {n}" not in docs
              and not re.search(rf'(tool|bench_run)\("{n}"|\("{n}", \[|"vpr_edge_bench", "{n}"', tests)]
    assert not unused, unused


def test_no_document_or_test_names_a_script_of_tools() -> None:
    """The experiments left ``tools/``: no document, test or CI script points there any more."""
    import re

    files = [ROOT / "README.md", *(ROOT / "docs").glob("*.md"), *(ROOT / "tests").glob("*.py"),
             *(ROOT / ".ci").iterdir()]
    stale = sorted({f"{f.name}: {m}" for f in files if f.is_file()
                    for m in re.findall(r"(?<![\w/.])tools/\w+\.py", f.read_text(errors="replace"))})
    assert not (ROOT / "tools").exists() and not stale, stale


def test_the_runtime_imports_nothing_of_the_lab_and_ships_without_it() -> None:
    """No module of ``vpr_edge`` imports ``vpr_edge_bench`` (at the top or inside a function), and the wheel's
    package list (pyproject's ``packages.find``) takes none of it."""
    import ast
    import tomllib

    from setuptools import find_packages

    found = []
    for path in (ROOT / "vpr_edge").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [node.module or ""] if isinstance(node, ast.ImportFrom) else \
                [a.name for a in node.names] if isinstance(node, ast.Import) else []
            found += [f"{path.relative_to(ROOT)}: {n}" for n in names if n.split(".")[0] == "vpr_edge_bench"]
    assert not found, found
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]["find"]
    packages = find_packages(where=str(ROOT), include=config["include"])
    assert "vpr_edge" in packages and "vpr_edge.evaluation" in packages
    assert not [p for p in packages if p.split(".")[0] == "vpr_edge_bench"], packages


@pytest.fixture(scope="module")
def every_stream(tmp_path_factory: pytest.TempPathFactory, small_refs: Path, small_queries: Path) -> Path:
    """Every kind of derived stream from the sample's first 24 frames (a 16-place map: the detour has places
    off it) with the folder's map (a small codebook)."""
    tmp = tmp_path_factory.mktemp("every-stream")
    shutil.copytree(small_refs, tmp / "pair" / "ref")
    shutil.copytree(small_queries, tmp / "pair" / "query")
    folder = tmp / "corridor"
    tool("derive-streams", "--dataset", str(tmp / "pair"), "--out", str(folder), "--map-places", "16")
    build = subprocess.run([sys.executable, "-m", "vpr_edge", "build-map", str(folder / "ref"), "-o",
                            str(folder / "map.npz"), "--components", "4"], capture_output=True, text=True, timeout=600)
    assert build.returncode == 0, build.stderr
    return folder


@pytest.mark.slow
def test_streams_folder_evaluates_each_stream_as_evaluate_does(every_stream: Path) -> None:
    """``StreamsFolder.evaluate``: one ``evaluate`` per stream kind, in kind order, each the library call."""
    from vpr_edge.evaluation import Source, Truth, evaluate
    from vpr_edge.matchers import get_matcher
    from vpr_edge_bench.folder import StreamsFolder

    modes = {"stream": get_matcher("stream"), "single": get_matcher("single")}
    got = dict(StreamsFolder(every_stream).check(map=True, ref=True).evaluate(modes, 2))
    assert list(got) == list(KINDS)
    for kind in ("aligned", "detour"):
        want = evaluate(Source(map=every_stream / "map.npz", queries=every_stream / kind),
                        Truth(gt=every_stream / f"{kind}.csv"), modes, 2)
        for m in modes:
            np.testing.assert_array_equal(got[kind].reports[m].refs, want.reports[m].refs)
            assert got[kind].reports[m].as_json() | {"ms_per_frame": 0} == want.reports[m].as_json() | \
                {"ms_per_frame": 0}
    pixels = dict(StreamsFolder(every_stream, ["speed2"]).evaluate(modes, 2, pixels=True))
    assert list(pixels) == ["speed2"] and pixels["speed2"].front is None


@pytest.mark.slow
def test_eval_streams_tables_every_mode_on_every_stream(every_stream: Path) -> None:
    """eval-streams: per stream and front end (the map, SeqSLAM's pixels) evaluate's table and --json in
    STREAMS/eval, the aligned stream's PR curves; R@1 and AUC tables with a row per front end and mode and a
    column per stream, the figures those JSON files hold; the detour's lost line per front end."""
    import json

    pytest.importorskip("matplotlib")
    text = tool("eval-streams", "--streams", str(every_stream), "--modes", "stream,single", "--tolerance", "2")
    out = every_stream / "eval"
    for kind in KINDS:
        for front in ("map", "pixels"):
            doc = json.loads((out / f"{kind}.{front}.json").read_text())
            assert set(doc["modes"]) == {"stream", "single"} and doc["tolerance"] == 2
            assert (out / f"{kind}.{front}.txt").read_text().startswith("mode ")
    assert sorted(p.name for p in out.glob("*.png")) == ["aligned.map.pr.png", "aligned.pixels.pr.png"]
    rows = {line.split("|")[1].strip(): [c.strip() for c in line.split("|")[2:-1]]
            for line in text.split("\nAUC")[0].splitlines() if line.startswith("| IFV") or line.startswith("| pixels")}
    assert list(rows) == ["IFV stream", "IFV single", "pixels stream", "pixels single"]
    for (label, cells), (front, mode) in zip(rows.items(), [("map", "stream"), ("map", "single"),
                                                            ("pixels", "stream"), ("pixels", "single")]):
        assert len(cells) == len(KINDS)
        for kind, cell in zip(KINDS, cells):
            r1 = json.loads((out / f"{kind}.{front}.json").read_text())["modes"][mode]["recall_at_1"]
            assert cell == f"{r1:.3f}", (label, kind)
    assert "stream mode, detour stream" in text and "  map: lost " in text and "  pixels: lost " in text
    assert "\nmapped right (" in text and "\nanswered right (" in text
    std = tool("eval-streams", "--streams", str(every_stream), "--modes", "single", "--tolerance", "2", "--fronts",
               "map", "--standardise", "--plot", "")
    cells = [line for line in std.split("\nAUC")[0].splitlines() if line.startswith("| IFV single")]
    assert len(cells) == 1 and "pixels" not in std      # the map's front end alone, its cosines standardised


@pytest.mark.slow
def test_front_end_cache_then_lines(every_stream: Path, tmp_path: Path) -> None:
    """front-end-cache writes each stream's matrix and what the matcher reads (kept on a second run), and
    front-end-lines scores every cached front end from them: a row per mode and stream, then the ranges."""
    other = tmp_path / "nordland-dev"
    shutil.copytree(every_stream, other, ignore=shutil.ignore_patterns("eval"))
    cache = tmp_path / "fronts"
    text = tool("front-end-cache", "--streams", str(every_stream), str(other), "--out", str(cache), "--fronts",
                "ifv,pixels", "--threads", "1")
    for ds in ("corridor", "nordland-dev"):
        for front in ("ifv", "pixels"):
            assert sorted(p.stem for p in (cache / ds / front).glob("*.npz") if p.stem != "map") == \
                sorted([*KINDS, "foreign"])
        with np.load(cache / ds / "ifv" / "aligned.npz", allow_pickle=False) as z:
            assert z["sim"].shape == (16, 16) and {"cue", "reach", "one_view", "truth"} <= set(z.files)
            sim = z["sim"]
    # without --standardise the cache keeps the plain cosines, whatever evaluate's default
    from vpr_edge.evaluation import sources
    from vpr_edge.map import MapQuery
    raw = sources.from_map(MapQuery(cache / "nordland-dev" / "ifv" / "map.npz", None, 1), other / "aligned", 16,
                           "aligned", lambda frame: None, standardise=False).cosine
    np.testing.assert_allclose(sim, raw, atol=1e-5)
    assert "single R@1 (tolerance 0) on the aligned stream" in text and "| corridor |" in text
    again = tool("front-end-cache", "--streams", str(every_stream), str(other), "--out", str(cache), "--fronts",
                 "ifv,pixels", "--threads", "1")
    assert again.count("exists") == 2 * 2 * (len(KINDS) + 1)
    lines = tool("front-end-lines", "--cache", str(cache), "--modes", "stream,stream")
    rows = [line.split("|")[1:-1] for line in lines.splitlines() if line.startswith("| corridor | ifv |")]
    per_stream = [r for r in rows if len(r) == 14 and r[3].strip() in (*KINDS, "foreign")]
    assert {(r[2].strip(), r[3].strip()) for r in per_stream} == {(m, k) for m in ("stream", "stream")
                                                                   for k in (*KINDS, "foreign")}
    assert any(r[2].strip() == "`stream`" for r in rows)        # the ranges' table
    # each line from a labelled drive's calibration: that drive left out of the rows
    fitted = tool("front-end-lines", "--cache", str(cache), "--modes", "stream", "--calibrate-on", "aligned")
    assert "each line from a calibration on aligned" in fitted
    cells = [line.split("|")[4].strip() for line in fitted.splitlines() if line.startswith("| corridor | ifv |")]
    assert {c for c in cells if c in (*KINDS, "foreign")} == {*KINDS, "foreign"} - {"aligned"}
    # a drive on the other half of the map too short to calibrate on: one line, before the work
    short = subprocess.run([sys.executable, "-m", "vpr_edge_bench", "front-end-lines", "--cache", str(cache),
                            "--modes", "stream", "--calibrate-on", "aligned", "--half", "second"],
                           capture_output=True, text=True)
    assert short.returncode == 2 and "aligned.npz: fewer than 20 frames on the first half" in short.stderr
    assert "Traceback" not in short.stderr and "| corridor |" not in short.stdout


def test_front_end_line_targets_count_as_a_plain_loop() -> None:
    """front-end-lines' count of the streams that meet each target of the line, against the targets counted one
    stream at a time: eligible where the best line reaches at least half the best R@1, a NaN gap not counted, a
    stream without one-view frames judged on every frame."""
    from vpr_edge_bench.line_targets import StreamFigures, count_text, targets

    nan = float("nan")
    rng = np.random.default_rng(3)
    streams = [StreamFigures(*rng.uniform(0, 1, 6).round(2), rng.uniform(0.9, 1) if i % 3 == 0 else nan)
               for i in range(40)]
    streams[5] = StreamFigures(0.8, nan, nan, 0.0, 0.1, nan, nan)   # a silent stream: no answers, no gap
    streams[6] = StreamFigures(0.8, 0.97, nan, 0.5, 0.6, 0.01, nan)  # eligible, no one-view frames, below 0.98
    streams[7] = StreamFigures(0.6, nan, nan, 0.0, 0.4, nan, nan)   # eligible and silent: no answer at all
    got = targets(streams, [1.0, 0.99, 0.5, 0.995], 0.98)
    gap_met = gap_all = elig = met = met_d = none = loud = det = det_met = beyond = loud_beyond = 0
    for f in streams:
        if f.line_gap == f.line_gap:
            gap_all += 1
            gap_met += f.line_gap <= 0.05
        if f.best_line > 0 and f.best_line >= 0.5 * f.best_r1:
            elig += 1
            met += f.answered_right >= 0.98
            nan_d = f.distinct_answered_right != f.distinct_answered_right
            d = f.answered_right if nan_d else f.distinct_answered_right
            met_d += d >= 0.98
            none += f.answered_right != f.answered_right
            loud += f.mapped_right >= 0.5 * f.best_r1
        elif f.best_r1 >= 0.5:   # followed, the target precision out of reach at half the best R@1
            beyond += 1
            loud_beyond += f.mapped_right >= 0.5 * f.best_r1
        if f.unmapped_lost == f.unmapped_lost:
            det += 1
            det_met += f.unmapped_lost >= 0.95
    assert got == {"line gap <= 0.05": (gap_met, gap_all), "precision >= target where eligible": (met, elig),
                   "... over distinct frames": (met_d, elig), "... none answered": (none, elig),
                   "not silent where eligible": (loud, elig),
                   "... followed, not eligible": (loud_beyond, beyond),
                   "detour unmapped lost >= 0.95": (det_met, det), "foreign lost >= 0.99": (3, 4)}
    assert count_text(got)["foreign lost >= 0.99"] == "3/4"
    assert beyond > 0 and elig > 0 and none > 0


def test_front_end_best_line_against_every_line_tried() -> None:
    """--oracle's line for one front end: the figures of a stream lost below a score, against plain counts; the
    line chosen meets at least as many of the acting targets (precision, detour, foreign imagery) as any other
    score, and at least as many not-silent streams as any other line meeting as many."""
    from vpr_edge_bench.line_targets import StreamAnswers, best_line, line_figures, targets

    rng = np.random.default_rng(8)
    streams = []
    for name in ("aligned", "speed2", "detour", "foreign"):
        n = 60
        scores = rng.uniform(0, 2, n)
        mapped = np.ones(n, bool) if name != "detour" else np.arange(n) < 40
        if name == "foreign":
            mapped = np.zeros(n, bool)
        right = mapped & (rng.random(n) < scores / 2)
        view = np.arange(n) < 5
        streams.append(StreamAnswers(name, scores, right, mapped, view, float(right.mean() + 0.1), 0.4))
    fig = line_figures(streams[2], 1.0)
    given = streams[2].scores >= 1.0
    assert fig.answered_right == pytest.approx((streams[2].right & given).sum() / given.sum())
    assert fig.mapped_right == pytest.approx((streams[2].right & given & streams[2].mapped).sum() / 40)
    assert fig.unmapped_lost == pytest.approx((~given[40:]).mean())
    s, r = streams[2].scores, streams[2].right   # the line gap: the best threshold at the delivered precision
    best = max([(r & (s >= x)).sum() / 40 for x in np.unique(s) if (r & (s >= x)).sum() / (s >= x).sum()
                >= fig.answered_right - 1e-12], default=0.0)
    assert fig.line_gap == pytest.approx(best - fig.mapped_right)
    assert line_figures(streams[3], 1.0).unmapped_lost == pytest.approx((streams[3].scores < 1.0).mean())

    def ranks(line: float) -> tuple[int, int]:
        figs = [line_figures(a, line) for a in streams]
        got = targets([f for f in figs if f.stream != "foreign"], [figs[3].unmapped_lost], 0.98)
        met = {k: v[0] for k, v in got.items()}
        return (met["... over distinct frames"] + met["detour unmapped lost >= 0.95"] + met["foreign lost >= 0.99"],
                met["not silent where eligible"] + met["... followed, not eligible"])

    line, counts = best_line(streams, 0.98)
    every = np.concatenate([a.scores for a in streams])
    tried = [ranks(x) for x in np.r_[np.quantile(every, np.linspace(0, 1, 200)), np.inf]]
    assert ranks(line) == max(tried)
    foreign = [line_figures(streams[3], line).unmapped_lost]
    assert counts == targets([line_figures(a, line) for a in streams[:3]], foreign, 0.98)

def test_front_end_line_reliability_and_lead_as_plain_loops() -> None:
    """The reliability table's bins (the last closed) and each frame's lead, against plain loops."""
    from vpr_edge_bench.line_targets import EDGES, lead, reliability

    rng = np.random.default_rng(5)
    p = np.concatenate([rng.uniform(0, 1, 300), [0.5, 0.8, 0.98, 1.0]])
    right = rng.uniform(0, 1, len(p)) < p
    got = reliability(p, right)
    for i, (lo, hi) in enumerate(zip(EDGES[:-1], EDGES[1:])):
        members = [r for q, r in zip(p, right) if lo <= q < hi or (i == len(EDGES) - 2 and q == hi)]
        assert got[i][1] == len(members)
        assert got[i][0] == pytest.approx(sum(members) / len(members))
    assert np.isnan(reliability(np.array([0.1]), np.array([True]))[0][0])

    sim = rng.normal(size=(30, 20))
    truth = np.full((30, 2), -1)
    truth[:, 0] = rng.integers(-1, 20, 30)
    want = []
    for q in range(30):
        t = truth[q, 0]
        if t < 0:
            continue
        near = [(sim[q, r], r) for r in range(max(0, t - 3), min(20, t + 4))]
        want.append(max(near)[1] - t)
    assert lead(sim, truth, 3).tolist() == want


def test_route_halves_cut_a_stream_as_plain_loops() -> None:
    """A cached stream against one half of its map: the truth inside shifted and first in its row, the frames
    from the first to the last of the half with the stream's unmapped frames next to them, the columns cut, the
    front end alone's R@1 counted again; foreign imagery whole; too few frames: None."""
    from vpr_edge_bench.route_halves import cut_stream, cut_truth, half_bounds, other_half

    assert half_bounds(9, "first") == (0, 4) and half_bounds(9, "second") == (4, 9)
    assert other_half("first") == "second" and other_half("second") == "first"
    with pytest.raises(ValueError, match="half must be one of first, second"):
        half_bounds(9, "middle")
    truth = np.array([[1, 2, -1], [5, 3, 4], [-1, -1, -1], [6, 7, 8]])
    got = cut_truth(truth, 3, 7)
    for row, cut in zip(truth, got):
        inside = [t - 3 for t in row if 3 <= t < 7]
        assert list(cut) == inside + [-1] * (len(row) - len(inside))
    rng = np.random.default_rng(4)
    t = np.r_[np.arange(0, 30), np.full(10, -1), np.arange(30, 60)]   # a detour leaving the map at place 30
    case = {"sim": rng.random((70, 60)).astype(np.float32), "truth": t[:, None], "cue": rng.random(70),
            "one_view": rng.random(70) < 0.2, "route": rng.random(60) < 0.5, "reach": np.int64(3),
            "tolerance": np.int64(2)}
    for half, rows in (("first", np.arange(0, 40)), ("second", np.arange(30, 70))):
        lo, hi = half_bounds(60, half)
        cut = cut_stream(case, lo, hi)
        assert cut is not None
        np.testing.assert_array_equal(cut["sim"], case["sim"][rows, lo:hi])
        np.testing.assert_array_equal(cut["truth"][:, 0], np.where(t[rows] >= 0, t[rows] - lo, -1))
        np.testing.assert_array_equal(cut["cue"], case["cue"][rows])
        np.testing.assert_array_equal(cut["one_view"], case["one_view"][rows])
        np.testing.assert_array_equal(cut["route"], case["route"][lo:hi])
        mapped = np.flatnonzero(cut["truth"][:, 0] >= 0)
        best = cut["sim"][mapped].argmax(axis=1)
        assert float(cut["single_r1_tol"]) == pytest.approx(np.mean(np.abs(best - cut["truth"][mapped, 0]) <= 2))
        assert float(cut["single_r1"]) == pytest.approx(np.mean(best == cut["truth"][mapped, 0]))
    foreign = dict(case, truth=np.full((70, 1), -1))
    whole = cut_stream(foreign, 30, 60)
    assert whole is not None and whole["sim"].shape == (70, 30)
    assert cut_stream(case, 0, 10) is None   # 10 frames of the half: fewer than 20


def test_probability_targets_count_as_plain_loops() -> None:
    """probability-targets' best line and ECE against plain loops over every line and every bin."""
    from vpr_edge_bench.experiments.probability_targets import best_line_recall, ece

    rng = np.random.default_rng(7)
    p = rng.random(200)
    right = rng.random(200) < p
    for precision in (0.6, 0.8, 0.95):
        best = 0.0
        for t in np.unique(p):
            given = p >= t
            if given.any() and right[given].mean() >= precision:
                best = max(best, (right & given).sum() / len(p))
        assert best_line_recall(p, right, precision) == pytest.approx(best)
    total = 0.0
    for b in range(10):
        sel = (np.minimum((p * 10).astype(int), 9)) == b
        if sel.any():
            total += abs(right[sel].mean() - p[sel].mean()) * sel.sum()
    assert ece(p, right) == pytest.approx(total / len(p))
