"""Positions in the map and answers as positions and times: cases worked by hand, the CLI end to end, and
bad positions and timestamps files refused in one line."""
from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from helpers import run, write_video
from vpr_edge.errors import VprError
from vpr_edge.map import load_map
from vpr_edge.positions import Positions, distances
from vpr_edge.positions.csv import read_csv

NAMES = ["a.jpg", "b.jpg", "c.jpg", "d.jpg"]


def _pos(coords, frame="local", heading=None) -> Positions:
    c = np.asarray(coords, np.float64)
    h = np.full(len(c), np.nan) if heading is None else np.asarray(heading, np.float64)
    return Positions(c, frame, h, np.full(len(c), np.nan))


def test_interpolation_and_distance_along_worked_by_hand() -> None:
    p = _pos([[0, 0], [10, 0], [10, 10]], heading=[90, 90, 0])
    np.testing.assert_allclose(p.along(), [0, 10, 20])
    coords, heading, along = p.at(1.5)
    np.testing.assert_allclose(coords, [10, 5])
    assert along == pytest.approx(15.0) and heading == pytest.approx(45.0)
    coords, heading, along = p.at(0.25)
    np.testing.assert_allclose(coords, [2.5, 0]) and along == pytest.approx(2.5)
    assert p.at(2.0)[2] == pytest.approx(20.0) and p.at(7.0)[2] == pytest.approx(20.0)   # clamped to the route
    wrap = _pos([[0, 0], [1, 0]], heading=[350, 10])
    assert wrap.at(0.5)[1] == pytest.approx(0.0)                    # through north, not through south
    assert np.isnan(_pos([[0, 0], [1, 0]]).at(0.5)[1])


def test_haversine_against_a_meridian_degree() -> None:
    d = distances(np.array([[52.0, 13.0]]), np.array([[53.0, 13.0], [52.0, 13.0]]), geo=True)
    assert d[0, 0] == pytest.approx(6_371_008.8 * np.pi / 180, rel=1e-9) and d[0, 1] == 0.0


def test_read_csv_by_name_in_order_and_with_gaps(tmp_path: Path) -> None:
    f = tmp_path / "p.csv"
    f.write_text("name,lat,lon,heading,alt\nd.jpg,52.003,13.0,,\na.jpg,52.0,13.0,370,34\nc.jpg,52.002,13.0,,\n")
    p = read_csv(f, NAMES)
    assert p.frame == "wgs84" and p.interpolated == 1                # b.jpg: no row, placed between a and c
    np.testing.assert_allclose(p.coords[:, 0], [52.0, 52.001, 52.002, 52.003])
    assert p.heading[0] == pytest.approx(10.0) and p.altitude[0] == 34 and np.isnan(p.heading[1])
    f.write_text("x,y\n0,0\n,\n4,0\n6,0\n")                          # in order, one row without a fix
    np.testing.assert_allclose(read_csv(f, NAMES).coords[:, 0], [0, 2, 4, 6])


@pytest.mark.parametrize("text, problem", [
    ("x,y\n0,0\n1,0\n", "2 positions but 4 references"),
    ("x,y,lat,lon\n0,0,1,1\n", "not both"),
    ("a,b\n0,0\n", "x,y (metres) or lat,lon"),
    ("name,x,y\na.jpg,0,zero\n", "line 2: y 'zero' is not a number"),
    ("name,x,y\na.jpg,0,0\nz.jpg,1,1\n", "'z.jpg' is not one of the references"),
    ("name,lat,lon\na.jpg,95,0\nd.jpg,0,0\n", "latitude outside"),
    ("name,x,y\nb.jpg,0,0\nd.jpg,1,1\n", "before the first position"),
    ("name,x,y\na.jpg,0,\n", "give both x and y"),
    ("x,y\n", "no positions"),
])
def test_read_csv_refuses(tmp_path: Path, text: str, problem: str) -> None:
    f = tmp_path / "p.csv"
    f.write_text(text)
    with pytest.raises(VprError, match=problem.replace("(", r"\(").replace(")", r"\)")) as e:
        read_csv(f, NAMES)
    assert str(e.value).startswith(str(f)) and "\n" not in str(e.value)


@pytest.fixture(scope="module")
def positioned(tmp_path_factory: pytest.TempPathFactory, small_refs: Path) -> Path:
    w = tmp_path_factory.mktemp("pos")
    names = sorted(p.name for p in small_refs.glob("*.jpg"))
    with open(w / "pos.csv", "w") as f:                          # a straight route along y, 2 m apart
        f.write("name,x,y,heading\n" + "".join(f"{n},5.0,{2.0 * i},0\n" for i, n in enumerate(names)))
    proc = run("build-map", small_refs, "-o", w / "map.npz", "--components", "4", "--pca-dim", "0", "--positions",
               w / "pos.csv")
    assert proc.returncode == 0, proc.stderr
    return w


@pytest.mark.slow
def test_map_positions_answers_and_stamps(positioned: Path, small_queries: Path, tmp_path: Path) -> None:
    pm = load_map(positioned / "map.npz")
    assert pm.positions.frame == "local" and pm.positions.coords[3].tolist() == [5.0, 6.0]
    info = json.loads(run("info", positioned / "map.npz").stdout)
    assert info["route"]["length_m"] == 46.0 and info["route"]["extent"]["y"] == [0.0, 46.0]
    names = sorted(p.name for p in small_queries.glob("*.jpg"))
    (tmp_path / "t.csv").write_text("frame,stamp\n" + "".join(f"{n},{100 + i / 4}\n" for i, n in enumerate(names)))
    for mode in ("stream", "stream-rules"):
        proc = run("localize", "-m", positioned / "map.npz", "-s", small_queries, "--timestamps", tmp_path / "t.csv",
                   "--format", "jsonl", "--mode", mode)
        assert proc.returncode == 0, proc.stderr
        lines = [json.loads(x) for x in proc.stdout.splitlines()]
        assert [m["stamp"] for m in lines] == [100 + i / 4 for i in range(24)]
        for m in lines:
            if m["lost"]:
                assert m["ref_index"] is None and m["x"] is None and m["along_m"] is None
            else:   # on the route, within one reference (2 m) of the answered reference, heading as mapped
                assert m["x"] == 5.0 and abs(m["y"] - 2.0 * m["ref_index"]) <= 1.0 and m["heading"] == 0.0
                assert m["along_m"] == m["y"] and m["lat"] is None
        assert any(not m["lost"] for m in lines)
    # stream-rules follows half-reference steps: some answers lie between references
    assert any(m["y"] % 2.0 == 1.0 for m in lines if not m["lost"]), "no answer between references"


@pytest.mark.slow
def test_append_extends_positions(positioned: Path, small_refs: Path, tmp_path: Path) -> None:
    shutil.copy(positioned / "map.npz", tmp_path / "map.npz")
    more = tmp_path / "more"
    more.mkdir()
    for f in sorted(small_refs.glob("*.jpg"))[:3]:
        shutil.copy(f, more / f"x{f.name}")
    (tmp_path / "more.csv").write_text("x,y\n5,50\n5,52\n5,54\n")
    no = run("build-map", more, "-o", tmp_path / "map.npz", "--append")
    assert no.returncode == 2 and "give --positions" in no.stderr
    geo = tmp_path / "geo.csv"
    geo.write_text("lat,lon\n1,1\n1,2\n1,3\n")
    mixed = run("build-map", more, "-o", tmp_path / "map.npz", "--append", "--positions", geo)
    assert mixed.returncode == 2 and "two frames" in mixed.stderr
    ok = run("build-map", more, "-o", tmp_path / "map.npz", "--append", "--positions", tmp_path / "more.csv")
    assert ok.returncode == 0, ok.stderr
    pm = load_map(tmp_path / "map.npz")
    assert len(pm.positions) == 27 and pm.positions.coords[-1].tolist() == [5.0, 54.0]


@pytest.mark.slow
def test_video_frames_carry_their_time(positioned: Path, small_queries: Path, tmp_path: Path) -> None:
    video = write_video(tmp_path / "q.avi", small_queries, 5)          # 10 frames a second
    proc = run("localize", "-m", positioned / "map.npz", "-s", video, "--mode", "single")
    assert proc.returncode == 0, proc.stderr
    stamps = [float(r["stamp"]) for r in csv.DictReader(proc.stdout.splitlines())]
    np.testing.assert_allclose(stamps, [0.0, 0.1, 0.2, 0.3, 0.4], atol=1e-6)
    bad = run("localize", "-m", positioned / "map.npz", "-s", video, "--timestamps", tmp_path / "none.csv")
    assert bad.returncode == 2 and "applies to a folder" in bad.stderr


def test_timestamps_file_refused(tmp_path: Path) -> None:
    from vpr_edge.frames.images import read_stamps

    f = tmp_path / "t.csv"
    for text, problem in (("frame,stamp\na.jpg,1\n", "no stamp for 1 frame"), ("a,b\n", "frame,stamp"),
                          ("frame,stamp\na.jpg,x\nb.jpg,2\n", "line 2"), ("frame,stamp\na.jpg,inf\nb.jpg,1\n", "finite")):
        f.write_text(text)
        with pytest.raises(VprError, match=problem):
            read_stamps(f, ["a.jpg", "b.jpg"])


def test_the_json_schema_names_the_fields_in_order() -> None:
    from vpr_edge.api import FIELDS, Match

    schema = json.loads((Path(__file__).resolve().parent.parent / "docs" / "results-line.schema.json").read_text())
    assert schema["required"] == list(FIELDS) == list(schema["properties"])
    line = Match(3, "f.jpg", 4, "r.jpg", 1.5, False, 12.5, lat=52.0, lon=13.0, heading=90.0, along_m=8.0).fields()
    kinds = {"integer": int, "number": (int, float), "string": str, "boolean": bool, "null": type(None)}
    for key, value in line.items():
        allowed = schema["properties"][key]["type"]
        allowed = [allowed] if isinstance(allowed, str) else allowed
        assert isinstance(value, tuple(kinds[t] for t in allowed)), (key, value)


def test_metre_errors_worked_by_hand() -> None:
    from vpr_edge.evaluation.metrics import metre_errors, metre_summary

    coords = np.array([[0.0, 0], [0, 4], [0, 8], [0, 30]])
    truth = np.array([[0, -1], [1, 2], [-1, -1], [3, -1]])      # query 1 has two correct references
    refs = np.array([1, 0, 2, 0])
    err = metre_errors(refs, truth, coords, geo=False)
    np.testing.assert_allclose(err[[0, 1, 3]], [4.0, 4.0, 30.0]) and np.isnan(err[2])
    s = metre_summary(err, lost=np.array([False, False, False, True]))
    assert s["median_m"] == 4.0 and s["within_5m"] == pytest.approx(2 / 3) and s["within_25m"] == pytest.approx(2 / 3)
    assert metre_summary(err, lost=np.zeros(4, bool))["within_25m"] == pytest.approx(2 / 3)   # 30 m is outside


@pytest.mark.slow
def test_evaluate_reports_metres_with_map_positions(positioned: Path, small_queries: Path, tmp_path: Path) -> None:
    from vpr_edge.evaluation.truth import write_ground_truth

    write_ground_truth(tmp_path / "gt.csv", [[i] for i in range(24)])
    proc = run("evaluate", "-m", positioned / "map.npz", "-q", small_queries, "--gt", tmp_path / "gt.csv",
               "--modes", "single,dtw", "--tolerance", "0", "--json", tmp_path / "e.json")
    assert proc.returncode == 0, proc.stderr
    assert "error in metres" in proc.stdout
    doc = json.loads((tmp_path / "e.json").read_text())
    assert doc["schema_version"] == 9
    m = doc["modes"]["dtw"]["metres"]
    assert m["median_m"] == 0.0 and m["within_5m"] >= doc["modes"]["dtw"]["recall_at_1"]   # 2 m spacing


def _jpeg_with_gps(path: Path, lat: float, lon: float, direction: float | None = None) -> None:
    """A real JPEG whose EXIF holds GPS tags (IFD0 -> GPS IFD; little-endian TIFF), written by hand."""
    import struct

    import cv2

    def rationals(deg: float) -> bytes:
        d = abs(deg)
        dd, mm = int(d), int((d - int(d)) * 60)
        ss = round(((d - dd) * 60 - mm) * 60 * 1000)
        return struct.pack("<6I", dd, 1, mm, 1, ss, 1000)

    entries = [(1, 2, 2, b"N\0" if lat >= 0 else b"S\0"), (2, 5, 3, rationals(lat)),
               (3, 2, 2, b"E\0" if lon >= 0 else b"W\0"), (4, 5, 3, rationals(lon))]
    if direction is not None:
        entries.append((17, 5, 1, struct.pack("<2I", round(direction * 100), 100)))
    gps_at = 8 + 2 + 12 + 4                                    # after the TIFF header and IFD0 (one entry)
    data_at = gps_at + 2 + 12 * len(entries) + 4
    ifd, data = b"", b""
    for tag, kind, count, value in entries:
        if len(value) <= 4:
            ifd += struct.pack("<HHI", tag, kind, count) + value.ljust(4, b"\0")
        else:
            ifd += struct.pack("<HHII", tag, kind, count, data_at + len(data))
            data += value
    tiff = (b"II*\0" + struct.pack("<I", 8) + struct.pack("<H", 1) + struct.pack("<HHII", 0x8825, 4, 1, gps_at)
            + struct.pack("<I", 0) + struct.pack("<H", len(entries)) + ifd + struct.pack("<I", 0) + data)
    app1 = b"Exif\0\0" + tiff
    ok, jpg = cv2.imencode(".jpg", np.full((120, 160, 3), 128, np.uint8))
    jpg = jpg.tobytes()
    path.write_bytes(jpg[:2] + b"\xff\xe1" + struct.pack(">H", len(app1) + 2) + app1 + jpg[2:])


def test_positions_from_exif_gps(tmp_path: Path) -> None:
    pytest.importorskip("exifread")
    from vpr_edge.positions.exif import from_exif

    files = [tmp_path / f"{i}.jpg" for i in range(4)]
    _jpeg_with_gps(files[0], 52.5, 13.25, direction=90.0)
    cv2 = pytest.importorskip("cv2")
    cv2.imwrite(str(files[1]), np.zeros((120, 160, 3), np.uint8))       # no GPS: placed between its neighbours
    _jpeg_with_gps(files[2], 52.5010, 13.25)
    _jpeg_with_gps(files[3], -33.5, -70.75)
    p = from_exif(files)
    assert p.frame == "wgs84" and p.interpolated == 1
    np.testing.assert_allclose(p.coords, [[52.5, 13.25], [52.5005, 13.25], [52.501, 13.25], [-33.5, -70.75]],
                               atol=1e-6)
    assert p.heading[0] == pytest.approx(90.0) and np.isnan(p.heading[2])


@pytest.mark.slow
def test_build_map_positions_exif(tmp_path: Path) -> None:
    pytest.importorskip("exifread")
    refs = tmp_path / "refs"
    refs.mkdir()
    for i in range(4):
        _jpeg_with_gps(refs / f"{i}.jpg", 60.0 + i * 0.001, 10.0)
    proc = run("build-map", refs, "-o", tmp_path / "m.npz", "--components", "2", "--positions", "exif")
    assert proc.returncode == 0, proc.stderr
    info = json.loads(run("info", tmp_path / "m.npz").stdout)["route"]
    assert info["frame"] == "wgs84" and info["length_m"] == pytest.approx(3 * 111.195, rel=2e-3)   # 0.001 deg of latitude: 111.2 m


@pytest.mark.slow
def test_evaluate_draws_the_matrix_and_the_route(positioned: Path, small_queries: Path, tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    import cv2

    from vpr_edge.evaluation.truth import write_ground_truth

    write_ground_truth(tmp_path / "gt.csv", [[i] for i in range(24)])
    proc = run("evaluate", "-m", positioned / "map.npz", "-q", small_queries, "--gt", tmp_path / "gt.csv",
               "--modes", "single,stream", "--plot-matrix", tmp_path / "m.png", "--plot-route", tmp_path / "r.png")
    assert proc.returncode == 0, proc.stderr
    for png in ("m.png", "r.png"):
        image = cv2.imread(str(tmp_path / png))
        assert image is not None and min(image.shape[:2]) > 300 and image.std() > 10      # a real figure
    wrote = {line.split()[2] for line in proc.stderr.splitlines() if line.startswith("vpr-edge: wrote ")}
    assert wrote == {str(tmp_path / "m.png"), str(tmp_path / "r.png")}                   # each named on stderr
    sim = np.random.default_rng(0).random((24, 24))
    np.save(tmp_path / "s.npy", sim)
    # without positions: the reference answered against the frame
    plain = run("evaluate", "--similarity", tmp_path / "s.npy", "--gt", tmp_path / "gt.csv", "--plot-route",
                tmp_path / "x.png", "--modes", "single,stream")
    assert plain.returncode == 0, plain.stderr
    assert f"vpr-edge: wrote {tmp_path / 'x.png'} " in plain.stderr
    image = cv2.imread(str(tmp_path / "x.png"))
    assert image is not None and min(image.shape[:2]) > 300 and image.std() > 10


@pytest.mark.slow
def test_gt_positions_from_the_map(positioned: Path, small_queries: Path, tmp_path: Path) -> None:
    """Query positions against the map's own: within 1 m of a reference 2 m apart is that reference alone."""
    (tmp_path / "q.csv").write_text("x,y\n" + "".join(f"5.0,{2.0 * i + 0.5}\n" for i in range(24)))
    a = run("evaluate", "-m", positioned / "map.npz", "-q", small_queries, "--gt-positions", "map",
            tmp_path / "q.csv", "--radius", "1", "--modes", "dtw", "--tolerance", "0", "--json", tmp_path / "a.json")
    assert a.returncode == 0, a.stderr
    from vpr_edge.evaluation.truth import write_ground_truth

    write_ground_truth(tmp_path / "gt.csv", [[i] for i in range(24)])
    b = run("evaluate", "-m", positioned / "map.npz", "-q", small_queries, "--gt", tmp_path / "gt.csv",
            "--modes", "dtw", "--tolerance", "0", "--json", tmp_path / "b.json")
    assert b.returncode == 0, b.stderr
    ra, rb = (json.loads((tmp_path / f).read_text())["modes"]["dtw"] for f in ("a.json", "b.json"))
    assert ra["recall_at_1"] == rb["recall_at_1"] and ra["auc"] == rb["auc"]
    (tmp_path / "g.csv").write_text("lat,lon\n" + "1,1\n" * 24)
    bad = run("evaluate", "-m", positioned / "map.npz", "-q", small_queries, "--gt-positions", "map", tmp_path / "g.csv")
    assert bad.returncode == 2 and "map's frame" in bad.stderr and "two frames" in bad.stderr


GPX = """<?xml version="1.0" encoding="UTF-8"?>
<gpx version="1.1" creator="test" xmlns="http://www.topografix.com/GPX/1/1"><trk><trkseg>
<trkpt lat="60.0" lon="10.0"><ele>100</ele><time>2026-01-01T00:00:00Z</time></trkpt>
<trkpt lat="60.001" lon="10.0"><ele>110</ele><time>2026-01-01T00:00:10Z</time></trkpt>
<trkpt lat="60.001" lon="10.002"><time>2026-01-01T00:00:20Z</time></trkpt>
</trkseg></trk></gpx>
"""
T_GPX = 1767225600.0     # 2026-01-01T00:00:00Z


def test_gpx_track_matched_by_time_worked_by_hand(tmp_path: Path) -> None:
    pytest.importorskip("gpxpy")
    from vpr_edge.positions.gpx import from_gpx

    (tmp_path / "t.gpx").write_text(GPX)
    p = from_gpx(tmp_path / "t.gpx", np.array([0.0, 5.0, 10.0, 15.0]) + T_GPX)
    np.testing.assert_allclose(p.coords, [[60.0, 10.0], [60.0005, 10.0], [60.001, 10.0], [60.001, 10.001]])
    np.testing.assert_allclose(p.altitude[:3], [100, 105, 110]) and p.frame == "wgs84"
    assert p.interpolated == 2
    with pytest.raises(VprError, match="the track"):
        from_gpx(tmp_path / "t.gpx", np.array([T_GPX - 1.0]))
    (tmp_path / "bad.gpx").write_text("<gpx><trk>")
    with pytest.raises(VprError, match="bad.gpx: not a readable GPX track"):
        from_gpx(tmp_path / "bad.gpx", np.array([T_GPX]))


@pytest.mark.slow
def test_build_map_positions_from_gpx(tmp_path: Path, small_refs: Path) -> None:
    pytest.importorskip("gpxpy")
    (tmp_path / "t.gpx").write_text(GPX)
    names = sorted(p.name for p in small_refs.glob("*.jpg"))[:5]
    refs = tmp_path / "refs"
    refs.mkdir()
    for n in names:
        shutil.copy(small_refs / n, refs / n)
    (tmp_path / "s.csv").write_text("frame,stamp\n" + "".join(f"{n},{T_GPX + 2.5 * i}\n" for i, n in enumerate(names)))
    no_time = run("build-map", refs, "-o", tmp_path / "m.npz", "--positions", tmp_path / "t.gpx")
    assert no_time.returncode == 2 and "--timestamps" in no_time.stderr
    ok = run("build-map", refs, "-o", tmp_path / "m.npz", "--components", "2", "--positions", tmp_path / "t.gpx",
             "--timestamps", tmp_path / "s.csv")
    assert ok.returncode == 0, ok.stderr
    np.testing.assert_allclose(load_map(tmp_path / "m.npz").positions.coords[:, 0],
                               [60.0, 60.00025, 60.0005, 60.00075, 60.001])


def test_isotonic_against_scikit_learn_and_by_hand() -> None:
    from sklearn.isotonic import IsotonicRegression

    from vpr_edge.calibration import isotonic

    x, y = isotonic(np.array([1.0, 2.0, 3.0, 4.0]), np.array([0, 1, 0, 1]))
    np.testing.assert_allclose(x, [1.0, 2.5, 4.0]) and np.testing.assert_allclose(y, [0.0, 0.5, 1.0])
    rng = np.random.default_rng(0)
    for _ in range(20):
        s = rng.normal(size=60)
        c = rng.random(60) < 1 / (1 + np.exp(-2 * s))
        bx, by = isotonic(s, c)
        want = IsotonicRegression().fit(s, c.astype(float)).predict(np.sort(s))
        assert (np.diff(by) >= 0).all() and (np.diff(bx) > 0).all()
        np.testing.assert_allclose(np.unique(by.round(9)), np.unique(want.round(9)))   # the same optimum


@pytest.mark.slow
def test_calibrated_confidence_end_to_end(positioned: Path, small_queries: Path, tmp_path: Path) -> None:
    from vpr_edge.evaluation.truth import write_ground_truth

    write_ground_truth(tmp_path / "gt.csv", [[i] for i in range(24)])
    a = run("evaluate", "-m", positioned / "map.npz", "-q", small_queries, "--gt", tmp_path / "gt.csv",
            "--modes", "single,stream", "--save-calibration", tmp_path / "cal.json")
    assert a.returncode == 0, a.stderr
    out = run("localize", "-m", positioned / "map.npz", "-s", small_queries, "--mode", "single", "--calibration",
              tmp_path / "cal.json", "--format", "jsonl")
    assert out.returncode == 0, out.stderr
    lines = [json.loads(x) for x in out.stdout.splitlines()]
    conf = [(m["score"], m["confidence"]) for m in lines]
    assert all(0.0 <= c <= 1.0 for _, c in conf)
    ordered = sorted(conf)
    assert all(b[1] >= a[1] - 1e-9 for a, b in zip(ordered, ordered[1:]))   # never less confident at a higher score
    plain = [json.loads(x) for x in run("localize", "-m", positioned / "map.npz", "-s", small_queries,
                                        "--format", "jsonl", "--mode", "stream-rules").stdout.splitlines()]
    assert all(m["confidence"] is None for m in plain)   # no calibration, no probability of its own
    own = [json.loads(x) for x in run("localize", "-m", positioned / "map.npz", "-s", small_queries,
                                      "--format", "jsonl").stdout.splitlines()]
    assert all(m["confidence"] == m["score"] for m in own if not m["lost"])   # stream's own probability
    (tmp_path / "bad.json").write_text('{"kind": "calibration", "schema": 1, "modes": {"stream": {"scores": [2, 1], '
                                       '"confidence": [0.1, 0.2], "n": 2, "tolerance": 1}}}')
    for f, problem in (("cal.json", "no calibration for mode dtw"), ("bad.json", "non-decreasing"),
                       ("gt.csv", "not a vpr-edge calibration")):
        bad = run("localize", "-m", positioned / "map.npz", "-s", small_queries, "--mode",
                  "dtw" if f == "cal.json" else "stream", "--calibration", tmp_path / f)
        assert bad.returncode == 2 and problem in bad.stderr and bad.stderr.count("\n") == 1, bad.stderr
