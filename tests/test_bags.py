"""ROS bags through the CLI: bags written here with rosbags (ROS 1, ROS 2 sqlite3 and MCAP), holding real
frames as CompressedImage or Image and a NavSatFix or Odometry topic, built into maps and localised."""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest

rosbags = pytest.importorskip("rosbags")   # write_bag needs it

from helpers import BAG_T0 as T0, run, write_bag  # noqa: E402


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["ros1", "ros2", "mcap"])
def test_build_and_localize_from_bags(kind: str, tmp_path: Path, small_refs: Path, small_queries: Path) -> None:
    suffix = {"ros1": ".bag", "ros2": "", "mcap": ""}[kind]
    refs = write_bag(tmp_path / f"drive{suffix}", sorted(small_refs.glob("*.jpg")), kind)
    queries = write_bag(tmp_path / f"drive2{suffix}", sorted(small_queries.glob("*.jpg")), kind, raw=kind == "ros2")
    proc = run("build-map", refs, "-o", tmp_path / "m.npz", "--topic", "/camera/image", "--positions-topic",
               "/gps/fix", "--components", "4", "--pca-dim", "0")
    assert proc.returncode == 0, proc.stderr
    info = json.loads(run("info", tmp_path / "m.npz").stdout)
    assert info["references"] == 24 and info["first"] == f"{refs.name}#0" and info["route"]["frame"] == "wgs84"
    # 24 images 0.1 s apart, fixes every 0.2 s 2e-5 degrees of latitude apart: 23 * 1e-5 deg = 25.6 m
    assert info["route"]["length_m"] == pytest.approx(23 * 1e-5 * math.pi / 180 * 6_371_008.8, abs=0.01)
    assert info["route"]["interpolated"] == 12                 # the odd images fall between two fixes
    out = run("localize", "-m", tmp_path / "m.npz", "-s", queries, "--topic", "/camera/image")
    assert out.returncode == 0, out.stderr
    rows = list(csv.DictReader(out.stdout.splitlines()))
    assert len(rows) == 24 and [float(r["stamp"]) for r in rows] == pytest.approx([T0 + i / 10 for i in range(24)])
    found = [r for r in rows if r["lost"] == "0"]
    assert found and all(r["lat"] and r["lon"] == "10.000000" and r["x"] == "" for r in found)
    from vpr_edge.evaluation.truth import write_ground_truth

    write_ground_truth(tmp_path / "gt.csv", [[i] for i in range(24)])
    ev = run("evaluate", "-m", tmp_path / "m.npz", "-q", queries, "--topic", "/camera/image", "--gt",
             tmp_path / "gt.csv", "--modes", "single", "--json", tmp_path / "e.json")
    assert ev.returncode == 0, ev.stderr
    doc = json.loads((tmp_path / "e.json").read_text())
    assert doc["n_queries"] == 24 and doc["modes"]["single"]["metres"]["within_25m"] is not None


@pytest.mark.slow
def test_odometry_positions_and_heading(tmp_path: Path, small_refs: Path) -> None:
    refs = write_bag(tmp_path / "odo.bag", sorted(small_refs.glob("*.jpg"))[:12], "ros1", odometry=True)
    proc = run("build-map", refs, "-o", tmp_path / "m.npz", "--topic", "/camera/image", "--positions-topic",
               "/odom", "--components", "4", "--pca-dim", "0")
    assert proc.returncode == 0, proc.stderr
    from vpr_edge.map import load_map

    p = load_map(tmp_path / "m.npz").positions
    assert p.frame == "local"
    np.testing.assert_allclose(p.coords[:, 0], np.arange(12) * 1.0, atol=1e-5)   # 2 m a 0.2 s fix: 1 m an image
    np.testing.assert_allclose(p.coords[:, 1], 1.0) and np.testing.assert_allclose(p.heading, 90.0)


def test_bag_bad_input(tmp_path: Path, small_refs: Path) -> None:
    refs = write_bag(tmp_path / "d.bag", sorted(small_refs.glob("*.jpg"))[:4], "ros1")
    (tmp_path / "not.bag").write_bytes(b"#ROSBAG V2.0\n garbage")
    cases = [
        (["build-map", refs, "-o", tmp_path / "m.npz"], "needs --topic TOPIC"),
        (["build-map", refs, "-o", tmp_path / "m.npz", "--topic", "/nope"], "no topic /nope"),
        (["build-map", refs, "-o", tmp_path / "m.npz", "--topic", "/gps/fix"], "carries sensor_msgs/msg/NavSatFix"),
        (["build-map", refs, "-o", tmp_path / "m.npz", "--topic", "/camera/image", "--positions-topic",
          "/camera/image"], "not sensor_msgs/msg/NavSatFix or nav_msgs/msg/Odometry"),
        (["build-map", small_refs, "-o", tmp_path / "m.npz", "--topic", "/camera/image"], "apply to a ROS bag"),
        (["localize", "-m", tmp_path / "none.npz", "-s", tmp_path / "not.bag", "--topic", "/x"], "not a readable"),
        (["build-map", tmp_path / "not.bag", "-o", tmp_path / "m.npz", "--topic", "/x"], "not a readable ROS bag"),
    ]
    for args, problem in cases:
        proc = run(*args)
        assert proc.returncode == 2 and problem in proc.stderr, (args, proc.stderr)
        assert "Traceback" not in proc.stderr and proc.stderr.strip().count("\n") == 0, proc.stderr
    assert not (tmp_path / "m.npz").exists()
