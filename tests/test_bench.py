"""``vpr-edge bench``: its table and record on a map of images and on a map of descriptors, which frames it
times, the setting it picks for a frame rate, and its bad input (one line, exit code 2, before the work)."""
from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from helpers import invoke
from vpr_edge.map import load_map
from vpr_edge.profiling.sweep import pick
from vpr_edge.profiling.inputs import load_frames, plan_frames
from vpr_edge.threads import cores


@pytest.fixture(scope="module")
def descriptor_map(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A map of 2,000 places of 64-dim global descriptors along a route (each like the one before)."""
    folder = tmp_path_factory.mktemp("descriptors")
    rng = np.random.default_rng(0)
    x = rng.normal(size=(2000, 64)).astype(np.float32)
    for i in range(1, len(x)):
        x[i] = 0.9 * x[i - 1] + np.sqrt(1 - 0.81) * x[i]
    np.save(folder / "route.npy", x)
    code, _, err = invoke("build-map", folder / "route.npy", "-o", folder / "route.map.npz")
    assert code == 0, err
    return folder / "route.map.npz"


@pytest.fixture(scope="module")
def image_map(tmp_path_factory: pytest.TempPathFactory, small_refs: Path) -> Path:
    """A map of the sample's first 24 references, built in its folder from ``refs`` (a relative path)."""
    folder = tmp_path_factory.mktemp("images")
    shutil.copytree(small_refs, folder / "refs")
    here = os.getcwd()
    os.chdir(folder)
    try:
        code, _, err = invoke("build-map", "refs", "-o", "refs.map.npz", "--components", "4", "--fit-iterations", "3")
    finally:
        os.chdir(here)
    assert code == 0, err
    return folder / "refs.map.npz"


def test_descriptor_map_has_no_decode_nor_front_end(descriptor_map: Path, tmp_path: Path) -> None:
    record_path = tmp_path / "bench.json"
    code, out, err = invoke("bench", descriptor_map, "--frames", "5", "--threads", "1", "--fps", "1",
                            "--json", record_path)
    assert code == 0, err
    lines = out.splitlines()
    assert "2,000 places" in lines[0] and "68 bytes a place" in lines[0]        # 64 int8 values + a scale
    assert "the map's first 5 places" in lines[2]
    row = lines[4].split()
    assert row[:4] == ["-", "1", "-", "-"] and float(row[6]) > 0                # no decode, no front end
    assert lines[-1].startswith("for 1 fps: 1 thread(s)") and "--threads 1" in lines[-1]
    record = json.loads(record_path.read_text())
    assert record["schema"] == 1 and record["host"]["cores"] == cores() and record["map"]["places"] == 2000
    (setting,) = record["settings"]
    assert setting["stages_ms"]["decode"] is None and setting["stages_ms"]["front"] is None
    assert setting["frames"] == 5 and setting["startup_s"] > 0 and setting["peak_rss_mb"] > 10
    assert setting["fps"] == pytest.approx(1e3 / setting["frame_ms"], rel=0.01)
    assert record["pick"] == setting and record["frames"]["kind"] == "places"


@pytest.mark.slow
def test_image_map_times_each_precision_and_stage(image_map: Path, tmp_path: Path) -> None:
    code, out, err = invoke("bench", image_map, "--frames", "3", "--threads", "1")
    assert code == 0, err
    lines = out.splitlines()
    assert "cnn + ifv" in lines[0] and "3 of the map's references from" in lines[2]
    rows = [line.split() for line in lines[4:-1]]
    assert [r[:2] for r in rows] == [["fp32", "1"], ["int8", "1"]]         # the bundled model has an int8 form
    for r in rows:
        stages = [float(v) for v in r[2:6]]
        # the four stages and their total are each printed rounded to 0.01: they may differ by 5 x 0.005
        assert all(v > 0 for v in stages) and float(r[6]) == pytest.approx(sum(stages), abs=0.026)
    assert lines[-1].startswith("fastest: ")
    # a frame rate nothing sustains: said, exit code 1
    code, out, _ = invoke("bench", image_map, "--frames", "2", "--threads", "1", "--fps", "1e6")
    assert code == 1 and "no setting sustains it here" in out.splitlines()[-1]
    elsewhere = tmp_path / "copied.map.npz"                # its references not here: synthetic frames
    shutil.copy(image_map, elsewhere)
    code, out, err = invoke("bench", elsewhere, "--frames", "2", "--threads", "1")
    assert code == 0 and "synthetic 160x120 JPEG frames" in out.splitlines()[2], err


def test_frames_are_the_references_where_they_are_else_synthetic(image_map: Path, tmp_path: Path) -> None:
    place_map = load_map(image_map)
    assert place_map.drives.items[0].source == "refs"      # relative: found beside the map, not in the cwd
    plan = plan_frames(place_map, image_map, 5)
    assert plan.kind == "references" and plan.stages == ("decode", "front", "encode", "match")
    assert [Path(f).name for f in plan.files] == place_map.names[:5]
    assert Path(plan.files[0]).parent == image_map.parent / "refs"
    elsewhere = tmp_path / "copied.map.npz"                # a map copied where its references are not
    shutil.copy(image_map, elsewhere)
    synthetic = plan_frames(load_map(elsewhere), elsewhere, 5)
    assert synthetic.kind == "synthetic" and synthetic.size == (160, 120) and not synthetic.files
    frames, decode = load_frames(synthetic, place_map, 5)
    assert len(frames) == 5 and decode(frames[0]).shape == (120, 160, 3)


def test_pick_prefers_fp32_then_fewest_threads() -> None:
    rows = [{"precision": p, "threads": t, "fps": f, "frame_ms": 1e3 / f}
            for p, t, f in (("fp32", 1, 15.0), ("fp32", 2, 28.0), ("int8", 1, 25.0), ("int8", 2, 45.0))]
    assert (pick(rows, 20)["precision"], pick(rows, 20)["threads"]) == ("fp32", 2)
    assert (pick(rows, 10)["precision"], pick(rows, 10)["threads"]) == ("fp32", 1)
    assert (pick(rows, 30)["precision"], pick(rows, 30)["threads"]) == ("int8", 2)
    assert pick(rows, 50) is None


@pytest.mark.parametrize("args, needle", [
    (["--fps", "0"], "--fps 0: give the camera's frame rate, above 0"),
    (["--fps", "-5"], "--fps -5"),
    (["--threads", str(cores() + 1)], f"this process may use {cores()} core(s)"),
    (["--threads", "0"], "--threads 0"),
    (["--frames", "0"], "--frames 0"),
    (["--json", "no/such/folder/b.json"], "does not exist"),
])
def test_bad_options_are_one_line_before_the_work(descriptor_map: Path, args: list[str], needle: str) -> None:
    code, out, err = invoke("bench", descriptor_map, *args)
    assert code == 2 and needle in err and err.count("\n") == 1 and out == "", (code, out, err)


def test_a_file_that_is_no_map_is_one_line(tmp_path: Path) -> None:
    for path, text in ((tmp_path / "notes.npz", "not a zip"), (tmp_path / "missing.npz", None)):
        if text is not None:
            path.write_text(text)
        code, out, err = invoke("bench", path)
        assert code == 2 and str(path) in err and err.count("\n") == 1 and out == "", err
