"""The live view / Rerun recording (``outputs.view``), the MCAP record (``outputs.mcap_record``), the pictures
beside them (``outputs.pictures``) and the Viewer vpr-edge starts (``outputs.viewer``), read back with Rerun's
and mcap's own readers."""
from __future__ import annotations

import json
import math
import os
import socket
import subprocess
import sys
import time
from collections import Counter, defaultdict
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from helpers import run
from vpr_edge.api import FIELDS, Match
from vpr_edge.errors import VprError
from vpr_edge.frames.frame import Frame
from vpr_edge.map.drives import Drives
from vpr_edge.outputs import extras
from vpr_edge.positions import Positions

rr = pytest.importorskip("rerun")          # the view extra (in the test extra: skipped only outside it)
mcap_reader = pytest.importorskip("mcap.reader")


def _map(n: int, source: str | None = None, positions: Positions | None = None) -> SimpleNamespace:
    """What the sinks read of a map: its names, drives and positions."""
    return SimpleNamespace(names=[f"{i:07d}.jpg" for i in range(n)], drives=Drives.single("ref", n, source),
                           positions=positions)


def _matches(n: int, lost: set[int], stamps: list[float | None] | None = None, **place) -> list[Match]:
    out = []
    for i in range(n):
        stamp = stamps[i] if stamps else None
        if i in lost:
            out.append(Match(i, f"q{i}.jpg", None, None, 1.0, True, stamp, lost_why="weak-view"))
        else:
            where = {k: f(i) for k, f in place.items()}
            out.append(Match(i, f"q{i}.jpg", i, f"{i:07d}.jpg", 9.0 + i, False, stamp, **where))
    return out


def _rows(path: Path) -> dict[str, list[dict]]:
    """Each entity's rows of a recording (``rerun.chunk.RrdReader``), as dicts of column -> value (times as
    integer nanoseconds)."""
    import pyarrow as pa
    from rerun.chunk import RrdReader

    rows: dict[str, list[dict]] = defaultdict(list)
    for chunk in RrdReader(path).stream():
        batch = chunk.to_record_batch()
        columns = {name: col.cast(pa.int64()) if pa.types.is_temporal(col.type) else col
                   for name, col in zip(batch.schema.names, batch.columns)}
        rows[chunk.entity_path].extend(pa.table(columns).to_pylist())
    return rows


def _frames_of(rows: list[dict]) -> list[int]:
    return sorted(r["frame"] for r in rows if r.get("frame") is not None)


def test_a_recording_holds_each_frame(tmp_path: Path, small_refs: Path, small_queries: Path) -> None:
    from vpr_edge.frames.images import load_image
    from vpr_edge.outputs.view import RerunSink

    n, lost = 8, {0, 4, 5}
    queries = sorted(small_queries.glob("*.jpg"))[:n]
    frames = [Frame(i, p.name, load_image(p)[:, :, ::-1].copy()) for i, p in enumerate(queries)]
    sink = RerunSink(_map(24, str(small_refs)), tmp_path / "m.npz", record=tmp_path / "run.rrd", stream="query",
                     lost_line=7.5)
    for m, f in zip(_matches(n, lost, [100.0 + 0.1 * i for i in range(n)]), frames):
        sink.write(m, f)
    assert not (tmp_path / "run.rrd").exists()            # written beside it, renamed at close
    sink.close(True)
    rows = _rows(tmp_path / "run.rrd")
    every = list(range(n))
    for entity in ("/query/image", "/reference/image", "/route/vehicle", "/timeseries/state/lost", "/answer"):
        assert _frames_of(rows[entity]) == every, entity
    answers = sorted(rows["/answer"], key=lambda r: r["frame"])
    assert [a["Answer:lost"][0] for a in answers] == [i in lost for i in every]
    assert [a["Answer:ref_index"][0] if a.get("Answer:ref_index") else None for a in answers] == \
        [None if i in lost else i for i in every]
    assert [a["Answer:frame"][0] for a in answers] == [f"q{i}.jpg" for i in every]
    assert [r["time"] for r in sorted(rows["/answer"], key=lambda r: r["frame"])][:2] == \
        [100_000_000_000, 100_100_000_000]                                  # the frames' own times (ns)
    vehicle = {r["frame"]: r["Points2D:positions"] for r in rows["/route/vehicle"]}
    assert vehicle[0] == [] and vehicle[1] == [[1.0, -0.0]] and vehicle[4] == vehicle[3] == [[3.0, -0.0]]
    said = [r["TextLog:text"][0] for r in sorted(rows["/status"], key=lambda r: r["frame"])]
    assert said == ["frame 0: lost (weak-view)", "frame 1: answering again", "frame 4: lost (weak-view)",
                    "frame 6: answering again"]
    # the reference's own image from the map's folder, a card where lost
    import cv2

    ref = {r["frame"]: bytes(r["EncodedImage:blob"][0]) for r in rows["/reference/image"]}
    img = cv2.imdecode(np.frombuffer(ref[1], np.uint8), cv2.IMREAD_COLOR)
    own = cv2.imread(str(small_refs / "0000001.jpg"))
    assert img.shape == own.shape and np.abs(img.astype(int) - own).mean() < 8
    card = cv2.imdecode(np.frombuffer(ref[0], np.uint8), cv2.IMREAD_COLOR)
    assert card.shape[:2] == (120, 160) and card.std() < 40
    from rerun.chunk import RrdReader

    assert len(RrdReader(tmp_path / "run.rrd").blueprints()) == 1          # the layout travels with it


def test_where_the_vehicle_is_drawn() -> None:
    from vpr_edge.outputs.view import answer_xy, route_xy

    geo = Positions(np.array([[52.0, 13.0], [52.001, 13.0], [52.001, 13.001]]), "wgs84", np.full(3, np.nan),
                    np.full(3, np.nan))
    xy = route_xy(_map(3, positions=geo))
    np.testing.assert_allclose(xy[1], [0.0, 111.195], atol=0.01)              # 0.001 deg north: 111.2 m
    np.testing.assert_allclose(xy[2], [111.195 * math.cos(math.radians(52.0)), 111.195], atol=0.01)
    m = Match(0, "q", 2, "r", 1.0, False, lat=52.001, lon=13.001)
    np.testing.assert_allclose(answer_xy(_map(3, positions=geo), xy, m), xy[2], atol=1e-6)
    plain = route_xy(_map(4))
    np.testing.assert_array_equal(plain[:, 0], [0, 1, 2, 3])
    assert answer_xy(_map(4), plain, Match(0, "q", None, None, 0.0, True)) is None


def test_reference_pictures_from_the_drive_folder_or_a_card(tmp_path: Path, small_refs: Path,
                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    import shutil

    from vpr_edge.outputs.pictures import ReferencePictures

    shutil.copytree(small_refs, tmp_path / "maps" / "ref")
    monkeypatch.chdir(tmp_path)
    here = ReferencePictures(_map(24, "ref"), tmp_path / "maps" / "m.npz")    # relative: from the map's folder
    assert here.file(3) == tmp_path / "maps" / "ref" / "0000003.jpg" and here.picture(3)[1]
    gone = ReferencePictures(_map(24, "elsewhere/ref"), tmp_path / "maps" / "m.npz")
    assert gone.file(3) is None and gone.picture(3)[1] is False
    assert ReferencePictures(_map(24, None), "m.npz").picture(0)[1] is False


def _mcap(path: Path) -> tuple[dict[str, list], object]:
    from mcap.reader import make_reader

    got: dict[str, list] = defaultdict(list)
    with open(path, "rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages(log_time_order=False):   # as written
            got[channel.topic].append((schema, channel, message))
        return got, reader.get_summary()


def test_mcap_one_answer_per_frame_at_the_frames_times(tmp_path: Path) -> None:
    from vpr_edge.outputs.mcap_record import ANSWER_SCHEMA, POSE, McapSink

    n, lost = 6, {2}
    stamps = [1_700_000_000.0 + 0.25 * i for i in range(n)]
    stamps[4] = None                                         # a frame without a time: its arrival
    positions = Positions(np.stack([np.zeros(n), 0.5 * np.arange(n)], 1), "local", np.zeros(n), np.full(n, np.nan))
    sink = McapSink(tmp_path / "run.mcap", _map(n, positions=positions), {"map": "m.npz"})
    before = time.time_ns()
    for m in _matches(n, lost, stamps, x=lambda i: 0.0, y=lambda i: 0.5 * i, heading=lambda i: 0.0,
                      along_m=lambda i: 0.5 * i):
        sink.write(m, None)
    sink.close(True)
    after = time.time_ns()
    got, summary = _mcap(tmp_path / "run.mcap")
    answers = got["/vpr/answer"]
    assert len(answers) == n and summary.statistics.channel_message_counts
    for i, (schema, channel, msg) in enumerate(answers):
        line = json.loads(msg.data)
        assert list(line) == list(FIELDS) and line["frame_index"] == i
        assert schema.name == "vpr_edge.Answer" and schema.encoding == "jsonschema"
        assert channel.message_encoding == "json"
        assert json.loads(schema.data) == ANSWER_SCHEMA
        if stamps[i] is None:
            assert before <= msg.log_time <= after
        else:
            assert msg.log_time == round(stamps[i] * 1e9)
        assert before <= msg.publish_time <= after
    poses = got[POSE]
    ys = [json.loads(m.data)["pose"]["position"]["y"] for _, _, m in poses]
    assert ys == [0.5 * i for i in range(n) if i not in lost]
    first = json.loads(poses[0][2].data)
    assert poses[0][0].name == "foxglove.PoseInFrame" and first["frame_id"] == "map"
    assert first["timestamp"] == {"sec": 1_700_000_000, "nsec": 0}
    q = first["pose"]["orientation"]               # heading 0 (+y) = yaw 90 degrees about +z
    assert q["z"] == pytest.approx(math.sqrt(0.5)) and q["w"] == pytest.approx(math.sqrt(0.5))
    assert "/vpr/location" not in got


def test_mcap_location_fix_on_a_lat_lon_map(tmp_path: Path) -> None:
    from vpr_edge.outputs.mcap_record import LOCATION, LOCATION_FIX, McapSink

    n = 3
    positions = Positions(np.stack([52.0 + 1e-4 * np.arange(n), np.full(n, 13.0)], 1), "wgs84", np.full(n, 90.0),
                          np.array([35.0, np.nan, 36.0]))
    sink = McapSink(tmp_path / "g.mcap", _map(n, positions=positions))
    for m in _matches(n, set(), [10.0, 10.5, 11.0], lat=lambda i: 52.0 + 1e-4 * i, lon=lambda i: 13.0,
                      heading=lambda i: 90.0):
        sink.write(m, None)
    sink.close(False)                              # stopped early: what was written is kept
    got, _ = _mcap(tmp_path / "g.mcap")
    fixes = [json.loads(m.data) for _, _, m in got[LOCATION]]
    assert [f["latitude"] for f in fixes] == [52.0, 52.0001, 52.0002]
    assert [f["altitude"] for f in fixes] == [35.0, 0.0, 36.0]
    assert fixes[0]["heading"] == pytest.approx(math.pi / 2) and fixes[0]["timestamp"] == {"sec": 10, "nsec": 0}
    assert got[LOCATION][0][0].name == "foxglove.LocationFix"
    assert set(fixes[0]) <= set(LOCATION_FIX["properties"]) and set(LOCATION_FIX["required"]) <= set(fixes[0])


def test_extras_are_checked_without_importing(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "mcap", None)       # as if not installed
    with pytest.raises(VprError, match=r"^-o FILE.mcap needs mcap: pip install 'vpr-edge\[mcap\]'$"):
        extras.require("mcap", "-o FILE.mcap")
    extras.require("view", "--view")                     # installed: passes


def test_the_viewer_vpr_edge_starts_has_analytics_off(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from vpr_edge.outputs import viewer

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    home = viewer.viewer_home()
    assert home == tmp_path / "cache" / "vpr-edge" / "rerun-viewer"
    env = viewer.viewer_env(home)
    # Rerun's own CLI reads the configuration the Viewer will read
    shown = subprocess.run([viewer.viewer_binary(), "analytics", "config"], env=env, capture_output=True, text=True,
                           timeout=60)
    assert shown.returncode == 0 and json.loads(shown.stdout)["analytics_enabled"] is False, shown.stdout
    assert "Welcome to Rerun" not in shown.stdout + shown.stderr            # not a first run: nothing to opt out of
    assert os.environ.get("XDG_CONFIG_HOME") != env["XDG_CONFIG_HOME"]     # the user's own settings untouched


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore:RRD file has no footer")      # the saver is stopped by a signal
def test_view_streams_to_a_listening_viewer(tmp_path: Path) -> None:
    """--view's path: to a Viewer already listening on the port (here Rerun's CLI saving what it receives, a
    Viewer without a window)."""
    from vpr_edge.outputs import viewer
    from vpr_edge.outputs.view import RerunSink

    port = _free_port()
    saver = subprocess.Popen([viewer.viewer_binary(), "--bind", "127.0.0.1", "--port", str(port), "--save",
                              str(tmp_path / "got.rrd")], env=viewer.viewer_env(viewer.viewer_home()),
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 30
        while not viewer.listening(port):
            assert saver.poll() is None and time.monotonic() < deadline
            time.sleep(0.1)
        sink = RerunSink(_map(5), tmp_path / "m.npz", view=True, port=port)
        for m in _matches(5, {2}):
            sink.write(m, None)
        sink.close(True)
        time.sleep(1.0)
    finally:
        saver.terminate()
        saver.wait(timeout=30)
    got = Counter()
    for entity, rows in _rows(tmp_path / "got.rrd").items():
        got[entity] = len(_frames_of(rows))
    assert got["/answer"] == 5 and got["/reference/image"] == 5 and got["/route/vehicle"] == 5


@pytest.fixture(scope="module")
def sample_map(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The bundled sample and a map of its references, as the quick start makes them (no positions)."""
    work = tmp_path_factory.mktemp("live")
    assert run("sample", "corridor", cwd=work).returncode == 0
    made = run("build-map", "corridor/ref", "-o", "m.npz", cwd=work)
    assert made.returncode == 0, made.stderr
    return work


@pytest.mark.slow
def test_localize_rerun_and_mcap_on_the_sample(sample_map: Path) -> None:
    """Each of the sample's 111 frames recorded: a query frame, a reference, a position and a lost flag; the
    MCAP record one answer per frame, at the frames' own times."""
    w = sample_map
    proc = run("localize", "-m", "m.npz", "-s", "corridor/query", "--rerun", "run.rrd", cwd=w)
    assert proc.returncode == 0, proc.stderr
    assert len(proc.stdout.splitlines()) == 112                      # the log still on stdout
    rows = _rows(w / "run.rrd")
    frames = list(range(111))
    for entity in ("/query/image", "/reference/image", "/route/vehicle", "/timeseries/state/lost"):
        assert _frames_of(rows[entity]) == frames, entity
    lost = [r["Scalars:scalars"][0] for r in sorted((r for r in rows["/timeseries/state/lost"] if r.get("frame")
                                                     is not None), key=lambda r: r["frame"])]
    lines = [ln.split(",") for ln in proc.stdout.splitlines()[1:]]
    assert lost == [float(ln[FIELDS.index("lost")]) for ln in lines]
    found = [r for r in rows["/reference/image"] if r.get("frame") is not None]
    assert len({bytes(r["EncodedImage:blob"][0]) for r in found}) > 50      # the references' own images
    names = sorted(p.name for p in (w / "corridor" / "query").iterdir())
    (w / "stamps.csv").write_text("frame,stamp\n" + "".join(f"{n},{1_700_000_000 + 0.1 * i:.1f}\n"
                                                             for i, n in enumerate(names)))
    proc = run("localize", "-m", "m.npz", "-s", "corridor/query", "--timestamps", "stamps.csv", "-o", "run.mcap",
               cwd=w)
    assert proc.returncode == 0 and proc.stdout == "", proc.stderr        # the answers go to the record
    got, summary = _mcap(w / "run.mcap")
    answers = got["/vpr/answer"]
    assert len(answers) == 111 and set(got) == {"/vpr/answer"}          # no positions: no place topic
    assert [m.log_time for _, _, m in answers] == [round((1_700_000_000 + 0.1 * i) * 1e9) for i in range(111)]
    assert [json.loads(m.data)["frame"] for _, _, m in answers] == names


@pytest.mark.slow
def test_localize_imports_no_extra_unless_asked(sample_map: Path) -> None:
    code = ("import sys; from vpr_edge.cli import main; sys.argv = ['vpr-edge', 'localize', '-m', 'm.npz', '-s', "
            "'corridor/query', '--max-frames', '3', '-o', 'a.csv']\n"
            "try:\n    main()\nexcept SystemExit as e:\n    assert not e.code, e.code\n"
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('rerun', 'rerun_bindings', 'mcap')))")
    proc = subprocess.run([sys.executable, "-c", code], cwd=sample_map, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == "[]"


@pytest.mark.slow
@pytest.mark.parametrize("args, hidden, needle", [
    (["--view"], "rerun", "--view needs rerun-sdk: pip install 'vpr-edge[view]'"),
    (["--rerun", "r.rrd"], "rerun", "--rerun needs rerun-sdk: pip install 'vpr-edge[view]'"),
    (["-o", "r.mcap"], "mcap", "-o FILE.mcap needs mcap: pip install 'vpr-edge[mcap]'")])
def test_a_missing_extra_is_one_line_before_the_work(sample_map: Path, args: list[str], hidden: str,
                                                     needle: str) -> None:
    hide = f"import sys; sys.modules['{hidden}'] = None; from vpr_edge.cli import main; sys.exit(main())"
    before = sorted(p.name for p in sample_map.iterdir())
    proc = subprocess.run([sys.executable, "-c", hide, "localize", "-m", "m.npz", "-s", "corridor/query", *args],
                          cwd=sample_map, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and proc.stderr.strip().splitlines() == [f"vpr-edge: error: {needle}"], proc.stderr
    assert sorted(p.name for p in sample_map.iterdir()) == before
