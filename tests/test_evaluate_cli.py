"""`vpr-edge evaluate` end to end: real frames, a similarity matrix without a model, pixels, bad input."""
from __future__ import annotations

import csv
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from helpers import assert_one_line_error, run
from vpr_edge.evaluation.run import map_same_view
from vpr_edge.evaluation.truth import one_view, write_ground_truth
from vpr_edge.map import load_map

JSON_KEYS = {"recall_at_1", "recall_at_5", "recall_at_10", "auc", "ap", "precision_at_full_recall",
             "recall_at_full_precision", "median_error", "lost_unmapped", "lost_mapped", "ms_per_frame", "lock_frames",
             "exit_frames", "answered_right", "mapped_right", "ece", "reliability", "one_view_frames",
             "distinct_answered_right", "distinct_mapped_right", "lost_why", "settings", "target_precision",
             "best_line_recall", "line_gap", "exact", "lead"}


@pytest.fixture(scope="module")
def eval_map(tmp_path_factory: pytest.TempPathFactory, small_refs: Path) -> Path:
    out = tmp_path_factory.mktemp("evalmap") / "m.map.npz"
    assert run("build-map", small_refs, "-o", out, "--components", "8", "--pca-dim", "32").returncode == 0
    return out


@pytest.fixture(scope="module")
def aligned_gt(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("gt") / "gt.csv"
    write_ground_truth(path, [[i] for i in range(24)])
    return path


def planted_similarity(tmp_path: Path, q: int = 40, r: int = 60) -> tuple[Path, Path]:
    rng = np.random.default_rng(0)
    places = np.arange(q) + 10
    sim = 0.3 * rng.normal(size=(q, r))
    sim[np.arange(q), places] += 1.0
    np.save(tmp_path / "s.npy", sim)
    write_ground_truth(tmp_path / "gt.csv", [[p] for p in places])
    return tmp_path / "s.npy", tmp_path / "gt.csv"


@pytest.mark.slow
def test_evaluate_real_frames_json_plot(tmp_path: Path, eval_map: Path, small_queries: Path,
                                        aligned_gt: Path) -> None:
    js, png, sim = tmp_path / "r.json", tmp_path / "pr.png", tmp_path / "s.npy"
    proc = run("evaluate", "--map", eval_map, "--queries", small_queries, "--gt", aligned_gt, "--json", js,
               "--plot", png, "--save-similarity", sim, "--modes", "single,stream,dtw,seqslam-online", "--details")
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(js.read_text())
    assert set(doc) == {"schema_version", "n_queries", "n_refs", "tolerance", "front_end", "modes"}
    assert doc["n_queries"] == 24 and doc["n_refs"] == 24 and doc["tolerance"] == 0
    assert set(doc["modes"]) == {"single", "stream", "dtw", "seqslam-online"}
    assert all(set(m) == JSON_KEYS for m in doc["modes"].values())
    assert doc["modes"]["dtw"]["recall_at_1"] > 0.9            # aligned sequences: fixed-end DTW is right
    assert png.read_bytes()[:4] == b"\x89PNG"
    assert f"vpr-edge: wrote {png} " in proc.stderr                     # each file written is named
    assert np.load(sim).shape == (24, 24)
    assert "R@1" in proc.stdout and "seqslam-online" in proc.stdout
    assert "away from where the map shows one view" in proc.stdout       # a map: its views are known
    # the mapped frames whose truth lies where the map shows one view: read from the map's own references, the
    # same count for every mode
    same_view = map_same_view(load_map(eval_map).stored.in_order())
    one_view_frames = int(one_view(np.array([[i] for i in range(24)]), same_view).sum())
    assert {m["one_view_frames"] for m in doc["modes"].values()} == {one_view_frames}
    why = doc["modes"]["stream"]["lost_why"]   # the stream matcher says why each lost frame is lost
    assert why and set(why) <= {"off-map", "ambiguous", "settling"} and "lost frames by why" in proc.stdout
    lost = round(doc["modes"]["stream"]["lost_mapped"] * 24)   # every frame here is mapped
    assert sum(w["mapped"] for w in why.values()) == lost and all(w["unmapped"] == 0 for w in why.values())
    assert doc["modes"]["single"]["lost_why"] == {} and doc["modes"]["dtw"]["lost_why"] == {}


@pytest.mark.slow
def test_evaluate_counts_the_frames_where_the_map_shows_one_view(tmp_path: Path, small_refs: Path,
                                                                 small_queries: Path, aligned_gt: Path) -> None:
    """A map whose drive stood at reference 8 for references 9-13 (the same image again): the aligned frames
    whose truth is 8-13 (6 of 24) are counted as at one view, in every mode; the console says what counted as
    correct (the ground truth's one reference a frame, and the tolerance beside it)."""
    refs = tmp_path / "refs"
    refs.mkdir()
    files = sorted(small_refs.glob("*.jpg"))
    for i, f in enumerate(files):
        shutil.copy(files[8] if 9 <= i <= 13 else f, refs / f.name)
    assert run("build-map", refs, "-o", tmp_path / "m.npz", "--components", "4").returncode == 0
    proc = run("evaluate", "--map", tmp_path / "m.npz", "--queries", small_queries, "--gt", aligned_gt,
               "--modes", "single,stream", "--json", tmp_path / "r.json", "--tolerance", "1")
    assert proc.returncode == 0, proc.stderr
    doc = json.loads((tmp_path / "r.json").read_text())
    assert {m["one_view_frames"] for m in doc["modes"].values()} == {6}
    assert proc.stdout.splitlines()[0].startswith("24 queries (24 of mapped places), 24 references; correct: a "
                                                  "reference the ground truth lists (up to 1 a query) or within 1 "
                                                  "of one; encoding ")


def test_evaluate_similarity_needs_no_model_nor_torch(tmp_path: Path) -> None:
    s, gt = planted_similarity(tmp_path)
    code = ("import sys, runpy; sys.argv = ['vpr-edge', 'evaluate', '--similarity', %r, '--gt', %r, '--json', %r]\n"
            "try:\n    runpy.run_module('vpr_edge', run_name='__main__')\nexcept SystemExit as e:\n"
            "    assert not e.code, e.code\n"
            "bad = [m for m in ('torch', 'onnx', 'sklearn', 'vpr_edge_export') if m in sys.modules]\n"
            "assert not bad, bad\n") % (str(s), str(gt), str(tmp_path / "r.json"))
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    doc = json.loads((tmp_path / "r.json").read_text())
    assert doc["n_queries"] == 40 and doc["n_refs"] == 60
    assert doc["modes"]["single"]["recall_at_1"] > 0.7 and doc["modes"]["stream"]["recall_at_1"] > 0.8


def test_evaluate_by_default_runs_the_default_mode_beside_the_baselines_in_a_short_table(tmp_path: Path) -> None:
    """Without --modes: localize's default mode and the baselines, three modes; --modes all: every mode over
    cosine similarities. The table has the main columns, each explained under it; --details adds the other
    columns and the tables behind them. Every file written is named on stderr, one line each."""
    from vpr_edge.evaluation.report import SHORT
    from vpr_edge.matchers import DEFAULT_MATCHER, MATCHERS

    s, gt = planted_similarity(tmp_path)
    outs = {"--json": "r.json", "--answers": "a.csv", "--save-similarity": "s2.npy", "--save-calibration": "c.json"}
    args = [a for opt, name in outs.items() for a in (opt, tmp_path / name)]
    proc = run("evaluate", "--similarity", s, "--gt", gt, *args)
    assert proc.returncode == 0, proc.stderr
    doc = json.loads((tmp_path / "r.json").read_text())
    assert list(doc["modes"]) == [DEFAULT_MATCHER, "single", "seqslam-online"]
    assert all(set(m) == JSON_KEYS for m in doc["modes"].values())          # --json keeps every figure
    lines = proc.stdout.splitlines()
    shown = list(SHORT)                                          # the default mode's score is a probability
    assert lines[1].split() == ["mode", *shown] and len(shown) + 1 <= 10
    assert [line.split()[0] for line in lines[2:5]] == list(doc["modes"])
    explained = [line.split()[0] for line in lines[6:6 + len(shown)]]
    assert explained == shown                                    # each column in a line under the table
    assert "lost frames by why" not in proc.stdout and "confidence against the share right" not in proc.stdout
    assert "--details" in proc.stdout and "--modes all" in proc.stdout
    wrote = [line for line in proc.stderr.splitlines() if line.startswith("vpr-edge: wrote ")]
    assert len(wrote) == len(outs) == len(proc.stderr.splitlines())
    assert {line.split()[2] for line in wrote} == {str(tmp_path / name) for name in outs.values()}
    assert all((tmp_path / name).exists() for name in outs.values())

    every = run("evaluate", "--similarity", s, "--gt", gt, "--modes", "all", "--details", "--json", tmp_path / "a.json")
    assert every.returncode == 0, every.stderr
    assert list(json.loads((tmp_path / "a.json").read_text())["modes"]) == \
        [n for n, m in MATCHERS.items() if m.scores == "cosine"]
    header = every.stdout.splitlines()[1].split()
    assert header[0] == "mode" and set(SHORT) < set(header) and {"R@5", "lock", "exit", "med.err"} < set(header)
    for table in ("the line:", "where the answers fall", "lost frames by why", "confidence against the share right"):
        assert table in every.stdout
    assert "--modes all" not in every.stdout and "--details:" not in every.stdout
    # a short table without a probability mode leaves ECE out
    plain = run("evaluate", "--similarity", s, "--gt", gt, "--modes", "single,stream-rules")
    assert plain.returncode == 0 and "ECE" not in plain.stdout and plain.stderr == "", plain.stderr
    assert_one_line_error(run("evaluate", "--similarity", s, "--gt", gt, "--modes", "all,nope"), "--modes",
                          "unknown matcher 'nope'", "or all")


@pytest.mark.slow
def test_evaluate_gt_matrix_and_positions(tmp_path: Path) -> None:
    s, _ = planted_similarity(tmp_path)
    m = np.zeros((40, 60), bool)
    m[np.arange(40), np.arange(40) + 10] = True
    np.save(tmp_path / "gt.npy", m)
    (tmp_path / "r.csv").write_text("x,y\n" + "".join(f"{5 * i},0\n" for i in range(60)))
    (tmp_path / "q.csv").write_text("x,y\n" + "".join(f"{5 * (i + 10) + 1},0\n" for i in range(40)))
    a = run("evaluate", "--similarity", s, "--gt", tmp_path / "gt.npy", "--modes", "single",
            "--json", tmp_path / "a.json")
    b = run("evaluate", "--similarity", s, "--gt-positions", tmp_path / "r.csv", tmp_path / "q.csv", "--radius", "2",
            "--modes", "single", "--json", tmp_path / "b.json")
    assert a.returncode == 0 and b.returncode == 0, a.stderr + b.stderr
    docs = [json.loads((tmp_path / f).read_text()) for f in ("a.json", "b.json")]
    for doc in docs:                                                      # timings differ run to run
        assert doc["modes"]["single"].pop("ms_per_frame") > 0
    assert docs[0] == docs[1]


def test_evaluate_pixels_front_end(tmp_path: Path, small_refs: Path, small_queries: Path, aligned_gt: Path) -> None:
    proc = run("evaluate", "--features", "pixels", "--refs", small_refs, "--queries", small_queries, "--gt",
               aligned_gt, "--modes", "single,seqslam", "--json", tmp_path / "p.json")
    assert proc.returncode == 0, proc.stderr
    assert json.loads((tmp_path / "p.json").read_text())["n_refs"] == 24


@pytest.mark.slow
def test_evaluate_bad_input(tmp_path: Path, eval_map: Path, small_queries: Path, aligned_gt: Path) -> None:
    s, gt = planted_similarity(tmp_path)
    short = tmp_path / "short.csv"
    write_ground_truth(short, [[i] for i in range(10)])
    rows40 = tmp_path / "rows40.csv"                         # the map's references, but another stream's rows
    write_ground_truth(rows40, [[i % 24] for i in range(40)])
    np.save(tmp_path / "one_d.npy", np.zeros(5))
    nan = np.load(s)
    nan[3, 4] = np.nan
    np.save(tmp_path / "nan.npy", nan)
    fake = tmp_path / "fake"
    (fake / "matplotlib").mkdir(parents=True)
    (fake / "matplotlib" / "__init__.py").write_text("raise ImportError('no matplotlib here')\n")
    existing = tmp_path / "keep.json"
    existing.write_text("{}")
    cases = [
        (["--similarity", s, "--gt", short], "short.csv"),
        (["--similarity", tmp_path / "one_d.npy", "--gt", gt], "2-D"),
        (["--similarity", tmp_path / "nan.npy", "--gt", gt], "NaN"),
        (["--map", eval_map, "--queries", small_queries, "--gt", gt], "names reference 49 but the map has only 24"),
        (["--map", eval_map, "--queries", small_queries, "--gt", rows40], "40 rows"),
        (["--similarity", s, "--gt", gt, "--modes", "single,nope"], "nope"),
        (["--similarity", s], "ground truth"),
        (["--similarity", s, "--gt", gt, "--map", eval_map], "one source"),
        (["--similarity", s, "--gt", gt, "--json", tmp_path], "is a folder"),
        (["--similarity", s, "--gt", gt, "--json", tmp_path / "no" / "r.json"], "does not exist"),
    ]
    for args, needle in cases:
        assert_one_line_error(run("evaluate", *args), needle)
    # --plot without matplotlib: one line, before any work, and nothing written
    proc = subprocess.run([sys.executable, "-m", "vpr_edge", "evaluate", "--similarity", str(s), "--gt", str(gt),
                           "--plot", str(tmp_path / "pr.png"), "--json", str(existing)], capture_output=True,
                          text=True, timeout=300, env={"PYTHONPATH": str(fake), "PATH": "/usr/bin:/bin"})
    assert_one_line_error(proc, "--plot needs matplotlib")
    assert proc.returncode == 2 and existing.read_text() == "{}" and not (tmp_path / "pr.png").exists()
    for given, needle in ((["--plot-matrix", "m.png"], "--plot-matrix needs matplotlib"),
                          (["--plot-route", "r.png", "--plot-matrix", "m.png"], "--plot-matrix, --plot-route need "
                                                                                 "matplotlib")):
        proc = subprocess.run([sys.executable, "-m", "vpr_edge", "evaluate", "--similarity", str(s), "--gt", str(gt),
                               *(str(tmp_path / a) if a.endswith(".png") else a for a in given)],
                              capture_output=True, text=True, timeout=300,
                              env={"PYTHONPATH": str(fake), "PATH": "/usr/bin:/bin"})
        assert_one_line_error(proc, needle)
        assert not (tmp_path / "m.png").exists() and not (tmp_path / "r.png").exists()


@pytest.mark.slow
def test_evaluate_window_reaches_the_stream_matcher(tmp_path: Path) -> None:
    """--param window=N sets the stream's local search as localize's does: each run equals the matcher called directly
    with that window (1,000 references: above the 400 where the default window engages)."""
    from vpr_edge.evaluation.scoring import evaluate_mode
    from vpr_edge.evaluation.truth import pad
    from vpr_edge.matchers import get_matcher

    s, gt = planted_similarity(tmp_path, q=200, r=1000)
    sim, truth = np.load(s), pad([[p] for p in np.arange(200) + 10])
    for window in (None, 0, 20):
        js = tmp_path / f"w{window}.json"
        extra = [] if window is None else ["--param", f"window={window}"]
        proc = run("evaluate", "--similarity", s, "--gt", gt, "--modes", "stream,single", "--json", js, *extra)
        assert proc.returncode == 0 and "does not apply" not in proc.stderr, proc.stderr
        got = json.loads(js.read_text())["modes"]["stream"]
        matcher = get_matcher("stream") if window is None else get_matcher("stream").with_params(window=window)
        want = evaluate_mode(matcher, sim, truth)
        assert got["recall_at_1"] == pytest.approx(want.recall[1]) and got["auc"] == pytest.approx(want.auc)
        assert got["settings"] == json.loads(json.dumps(want.settings))     # the window it ran with, recorded
        assert got["settings"]["window"] == (get_matcher("stream").params["window"] if window is None else window)
    proc = run("evaluate", "--similarity", s, "--gt", gt, "--modes", "single", "--param", "window=5")
    assert proc.returncode == 2 and "none of the modes single has a parameter 'window'" in proc.stderr, proc.stderr


@pytest.mark.slow
def test_evaluate_param_sets_matcher_parameters(tmp_path: Path) -> None:
    """--param KEY=VALUE reaches every chosen mode that has KEY (here stream-rules' bias and lock, and dtw-open's
    hub removal), runs as the matcher called directly with it, and is recorded in the settings."""
    from vpr_edge.evaluation.scoring import evaluate_mode
    from vpr_edge.evaluation.truth import pad
    from vpr_edge.matchers import get_matcher

    s, gt = planted_similarity(tmp_path)
    sim, truth = np.load(s), pad([[p] for p in np.arange(40) + 10])
    js = tmp_path / "p.json"
    proc = run("evaluate", "--similarity", s, "--gt", gt, "--modes", "single,stream-rules,dtw-open", "--json", js,
               "--param", "bias=1.5", "--param", "lock=4", "--param", "hubs=false")
    assert proc.returncode == 0, proc.stderr
    got = json.loads(js.read_text())["modes"]
    for name, over in (("stream-rules", {"bias": 1.5, "lock": 4.0}), ("dtw-open", {"hubs": False})):
        want = evaluate_mode(get_matcher(name).with_params(**over), sim, truth)
        assert got[name]["recall_at_1"] == pytest.approx(want.recall[1]) and got[name]["auc"] == pytest.approx(want.auc)
        assert got[name]["settings"] == json.loads(json.dumps(want.settings))
    assert got["stream-rules"]["settings"]["bias"] == 1.5 and got["single"]["settings"] == {"min_confidence": None}
    for args, needle in ((["--param", "nope=1"], "nope"), (["--param", "lock=x"], "not a number"),
                         (["--param", "decay=3"], "decay"), (["--modes", "single", "--param", "lock=3"], "lock"),
                         (["--param", "unique=1"], "unique must be in [0, 1)")):
        modes = [] if "--modes" in args else ["--modes", "single,stream-rules,dtw-open"]
        assert_one_line_error(run("evaluate", "--similarity", s, "--gt", gt, *modes, *args), needle)


def test_evaluate_scores_a_calibration_from_other_frames(tmp_path: Path) -> None:
    """--save-calibration on one stream, --calibration on another: the ECE and reliability table of that
    confidence over the answers given, per mode it holds; the answered / mapped shares always; a file without
    the modes refused."""
    s, gt = planted_similarity(tmp_path)
    cal, js = tmp_path / "cal.json", tmp_path / "r.json"
    assert run("evaluate", "--similarity", s, "--gt", gt, "--modes", "single,stream", "--save-calibration",
               cal).returncode == 0
    proc = run("evaluate", "--similarity", s, "--gt", gt, "--modes", "single,stream,dtw", "--calibration", cal,
               "--json", js)
    assert proc.returncode == 0, proc.stderr
    modes = json.loads(js.read_text())["modes"]
    for name, given in (("single", 40), ("stream", 40 - round(40 * modes["stream"]["lost_mapped"]))):
        r = modes[name]   # its own frames' answers given (a lost frame carries no confidence)
        assert 0.0 <= r["ece"] <= 0.1 and sum(b["n"] for b in r["reliability"]) == given
        assert 0.0 <= r["answered_right"] <= 1.0 and 0.0 <= r["mapped_right"] <= r["recall_at_1"] + 1e-9
    assert modes["dtw"]["ece"] is None and modes["dtw"]["reliability"] == []
    assert "ECE" in proc.stdout.splitlines()[1]
    other = tmp_path / "other.json"
    bad = run("evaluate", "--similarity", s, "--gt", gt, "--save-calibration", other, "--calibration-fit", "nope")
    assert_one_line_error(bad, "--calibration-fit", "'nope' is not one of 'logistic', 'isotonic'")
    assert bad.returncode == 2 and not other.exists()
    fitted = {}
    for fit in ("logistic", "isotonic"):   # each fit named in the file it writes
        assert run("evaluate", "--similarity", s, "--gt", gt, "--modes", "stream", "--save-calibration", other,
                   "--calibration-fit", fit).returncode == 0
        fitted[fit] = json.loads(other.read_text())["method"]
    assert fitted == {"logistic": "logistic", "isotonic": "isotonic"}
    bad = run("evaluate", "--similarity", s, "--gt", gt, "--modes", "dtw", "--calibration", cal)
    assert_one_line_error(bad, "cal.json", "no calibration for modes dtw")
    bad = run("evaluate", "--similarity", s, "--gt", gt, "--modes", "single", "--calibration", gt)
    assert_one_line_error(bad, "gt.csv", "not a vpr-edge calibration")


def test_evaluate_draws_a_calibrations_line_at_the_target_precision(tmp_path: Path) -> None:
    """--calibration with --target-precision: each mode it holds is lost below its drive's line at that
    precision (the file's), as localize draws it; without --target-precision, the mode's own line."""
    import csv

    from vpr_edge.calibration import load

    s, gt = planted_similarity(tmp_path)
    cal = tmp_path / "cal.json"
    saved = run("evaluate", "--similarity", s, "--gt", gt, "--modes", "stream-rules", "--save-calibration", cal)
    assert saved.returncode == 0, saved.stderr
    # it says each mode's line at the target: 40 frames do not show 0.98 (Wilson's bound: 40 of 40 show 0.937)
    assert "each mode's line" in saved.stdout and "stream-rules: none: these frames do not show 0.98" in saved.stdout
    line = load(cal, "stream-rules").line(0.9)
    proc = run("evaluate", "--similarity", s, "--gt", gt, "--modes", "stream-rules", "--calibration", cal,
               "--target-precision", "0.9", "--answers", tmp_path / "a.csv", "--json", tmp_path / "r.json")
    assert proc.returncode == 0, proc.stderr
    stream = json.loads((tmp_path / "r.json").read_text())["modes"]["stream-rules"]
    assert stream["settings"]["min_confidence"] == pytest.approx(line)
    rows = list(csv.DictReader(open(tmp_path / "a.csv")))
    assert [r["lost"] == "1" for r in rows] == [float(r["score"]) < line - 1e-5 for r in rows]
    assert run("evaluate", "--similarity", s, "--gt", gt, "--modes", "stream-rules", "--calibration", cal, "--json",
               tmp_path / "own.json").returncode == 0
    own = json.loads((tmp_path / "own.json").read_text())["modes"]["stream-rules"]["settings"]["min_confidence"]
    assert own == 1.0


def test_evaluate_target_precision_line_gap_and_answers(tmp_path: Path) -> None:
    """``--target-precision`` is stream's line; every mode gets the best line and the line gap; ``--answers``
    writes each frame's answer per mode; a target outside (0, 1) is one line, exit 2, before any output."""
    import csv

    s, gt = planted_similarity(tmp_path)
    proc = run("evaluate", "--similarity", s, "--gt", gt, "--modes", "stream-rules,stream", "--target-precision",
               "0.9", "--answers", tmp_path / "a.csv", "--json", tmp_path / "r.json", "--details")
    assert proc.returncode == 0, proc.stderr
    assert "line gap" in proc.stdout
    doc = json.loads((tmp_path / "r.json").read_text())
    prob = doc["modes"]["stream"]
    assert prob["settings"]["min_confidence"] == 0.9 and prob["target_precision"] == 0.9
    assert 0.0 <= prob["best_line_recall"] <= 1.0 and prob["line_gap"] is not None
    rows = list(csv.DictReader(open(tmp_path / "a.csv")))
    assert len(rows) == 80 and {r["mode"] for r in rows} == {"stream-rules", "stream"}
    assert all(r["probability"] == "" for r in rows if r["mode"] == "stream-rules")
    assert all(0.0 <= float(r["probability"]) <= 1.0 for r in rows if r["mode"] == "stream")
    lost = [r for r in rows if r["mode"] == "stream" and r["lost"] == "1"]
    assert all(float(r["probability"]) < 0.9 and r["why"] for r in lost)
    given = [r for r in rows if r["mode"] == "stream" and r["lost"] == "0"]
    # an answer given is at least the line sure, its score that probability
    assert given and all(float(r["score"]) == float(r["probability"]) >= 0.9 for r in given)
    # without --calibration, the probability's own reliability over every frame, against a plain loop
    p = np.array([float(r["probability"]) for r in rows if r["mode"] == "stream"])
    right = np.array([r["right"] == "1" for r in rows if r["mode"] == "stream"])
    ece = 0.0
    for b in range(10):
        members = [(q, ok) for q, ok in zip(p, right) if b / 10 <= q < (b + 1) / 10 or (b == 9 and q == 1.0)]
        if members:
            ece += len(members) / len(p) * abs(np.mean([ok for _, ok in members]) - np.mean([q for q, _ in members]))
    assert prob["ece"] == pytest.approx(ece, abs=1e-6) and sum(b["n"] for b in prob["reliability"]) == 80 // 2
    assert doc["modes"]["stream-rules"]["ece"] is None
    for bad in ("1", "0", "-0.5", "nan"):
        proc = run("evaluate", "--similarity", s, "--gt", gt, "--target-precision", bad, "--json", tmp_path / "x.json")
        assert proc.returncode == 2
        assert_one_line_error(proc, "--target-precision")
        assert not (tmp_path / "x.json").exists()


@pytest.mark.slow
def test_evaluate_agrees_with_a_count_from_localizes_own_output(tmp_path: Path) -> None:
    """On the sample, evaluate's default mode counts what localize writes: mapped frames answered right and
    answers right, counted from localize's CSV against the sample's ground truth (it lists +-2), at evaluate's
    default tolerance (the truth's own window)."""
    c = tmp_path / "corridor"
    assert run("sample", "corridor", "--to", c).returncode == 0
    m, out, js = tmp_path / "c.npz", tmp_path / "run.csv", tmp_path / "r.json"
    assert run("build-map", c / "ref", "-o", m).returncode == 0
    truth = {int(q): {int(r) for r in refs.split()}
             for q, refs in csv.reader((c / "ground_truth.csv").read_text().splitlines()[1:])}
    counted = []
    for switch in (["--raw-cosines"], []):   # raw cosines, and the standardised ones: the same chain both ways
        assert run("localize", "-m", m, "-s", c / "query", "-o", out, *switch).returncode == 0
        proc = run("evaluate", "--map", m, "--queries", c / "query", "--gt", c / "ground_truth.csv", "--json", js,
                   *switch)
        assert proc.returncode == 0, proc.stderr
        rows = list(csv.DictReader(out.read_text().splitlines()))
        given = [r for r in rows if r["lost"] == "0"]
        right = [r for r in given if int(r["ref_index"]) in truth[int(r["frame_index"])]]
        # lost where unsure, else right: 55 of 111 answered on raw cosines, 79 standardised (the default)
        assert len(rows) == 111 and len(right) >= (50 if switch else 70) and len(right) == len(given)
        stream = json.loads(js.read_text())["modes"]["stream"]
        assert stream["mapped_right"] == pytest.approx(len(right) / len(rows))
        assert stream["answered_right"] == pytest.approx(len(right) / len(given))
        counted.append(len(right))
    assert counted[1] > counted[0]   # the sample: 64 -> 78 mapped frames answered right
