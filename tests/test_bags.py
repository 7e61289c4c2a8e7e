"""ROS bags through the CLI: bags written here with rosbags (ROS 1, ROS 2 sqlite3 and MCAP), holding real
frames as CompressedImage or Image and a NavSatFix or Odometry topic, built into maps and localised."""
from __future__ import annotations

import csv
import json
import math
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

rosbags = pytest.importorskip("rosbags")

from rosbags.rosbag1 import Writer as Writer1  # noqa: E402
from rosbags.rosbag2 import StoragePlugin, Writer as Writer2  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

TS = get_typestore(Stores.ROS2_HUMBLE)
T0 = 1_700_000_000


def run(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "vpr_edge", *map(str, args)], capture_output=True, text=True,
                          timeout=600)


def _header(ts, i: int, dt: float = 0.1):
    t = T0 + i * dt
    Time, Header = ts.types["builtin_interfaces/msg/Time"], ts.types["std_msgs/msg/Header"]
    extra = {"seq": i} if "seq" in Header.__dataclass_fields__ else {}
    return Header(stamp=Time(sec=int(t), nanosec=int(round((t - int(t)) * 1e9))), frame_id="camera", **extra)


def _image_msg(ts, i: int, path: Path, raw: bool):
    bgr = cv2.imread(str(path))
    if raw:
        Image = ts.types["sensor_msgs/msg/Image"]
        h, w = bgr.shape[:2]
        return Image(header=_header(ts, i), height=h, width=w, encoding="bgr8", is_bigendian=0, step=w * 3,
                     data=np.ascontiguousarray(bgr).reshape(-1))
    Compressed = ts.types["sensor_msgs/msg/CompressedImage"]
    return Compressed(header=_header(ts, i), format="jpeg", data=np.frombuffer(cv2.imencode(".jpg", bgr)[1], np.uint8))


def _fix_msg(ts, i: int, odometry: bool):
    if odometry:   # along +x: yaw 0 (heading 90, clockwise from +y)
        m = ts.types
        pose = m["geometry_msgs/msg/Pose"](position=m["geometry_msgs/msg/Point"](x=2.0 * i, y=1.0, z=0.0),
                                           orientation=m["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))
        return m["nav_msgs/msg/Odometry"](
            header=_header(ts, i, 0.2), child_frame_id="base",
            pose=m["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
            twist=m["geometry_msgs/msg/TwistWithCovariance"](
                twist=m["geometry_msgs/msg/Twist"](linear=m["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                                                   angular=m["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)),
                covariance=np.zeros(36)))
    Status, Fix = ts.types["sensor_msgs/msg/NavSatStatus"], ts.types["sensor_msgs/msg/NavSatFix"]
    return Fix(header=_header(ts, i, 0.2), status=Status(status=0, service=1), latitude=60.0 + i * 2e-5,
               longitude=10.0, altitude=5.0, position_covariance=np.zeros(9), position_covariance_type=0)


def write_bag(path: Path, frames: list[Path], kind: str, raw: bool = False, odometry: bool = False) -> Path:
    """A bag with /camera/image (compressed, or raw ``bgr8``) at 10 Hz and /gps/fix (NavSatFix, or Odometry on
    /odom) at 5 Hz covering the images. ``kind``: ros1, ros2 (sqlite3) or mcap (ROS 2 MCAP storage)."""
    image_type = "sensor_msgs/msg/Image" if raw else "sensor_msgs/msg/CompressedImage"
    fix_topic, fix_type = ("/odom", "nav_msgs/msg/Odometry") if odometry else ("/gps/fix", "sensor_msgs/msg/NavSatFix")
    n_fix = math.ceil(len(frames) / 2) + 1
    if kind == "ros1":
        ts = get_typestore(Stores.ROS1_NOETIC)
        writer, serialize = Writer1(path), ts.serialize_ros1
    else:
        plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
        ts = TS
        writer, serialize = Writer2(path, version=9, storage_plugin=plugin), ts.serialize_cdr
    with writer as w:
        cam = w.add_connection("/camera/image", image_type, typestore=ts)
        fix = w.add_connection(fix_topic, fix_type, typestore=ts)
        for i, f in enumerate(frames):
            w.write(cam, int((T0 + i * 0.1) * 1e9), serialize(_image_msg(ts, i, f, raw), image_type))
        for i in range(n_fix):
            w.write(fix, int((T0 + i * 0.2) * 1e9), serialize(_fix_msg(ts, i, odometry), fix_type))
    return path


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
