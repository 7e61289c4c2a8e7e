"""A stream run as on a vehicle, with real processes: the log kept however the run ends (Ctrl-C, SIGTERM, a
limit, a closed pipe, a failure), the summary and the early "does not fit the map" warning, and the faults
of a fleet (two builds of one map, a build killed, an unwritable HOME, a map whose metadata does not fit
its arrays, an unopenable video, a ground truth that does not fit the map); and the pure parts alone."""
from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from vpr_edge.cli.common import flag
from vpr_edge.api import FIELDS, Match
from vpr_edge.errors import VprError
from vpr_edge.frames.frame import Frame
from vpr_edge.frames.limits import Limited
from vpr_edge.outputs.sink import ResultSink
from vpr_edge.outputs.log import ResultLog, part_path
from vpr_edge.outputs.summary import FIRST_STRETCH, RunSummary, reference_size, size_misfit
from vpr_edge.resources import sample_folder

CLI = [sys.executable, "-m", "vpr_edge"]


def _run(*args, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([*CLI, *map(str, args)], capture_output=True, text=True, timeout=300, **kw)


def _rows(path: Path) -> list[dict]:
    """The log's rows, read as CSV; every one whole (as many cells as the header)."""
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    assert rows[0] == list(FIELDS)
    assert all(len(r) == len(FIELDS) for r in rows[1:])
    return [dict(zip(FIELDS, r)) for r in rows[1:]]


def _match(i: int, lost: bool = False, why: str | None = None) -> Match:
    return Match(i, f"{i:07d}.jpg", None if lost else i, None if lost else f"r{i}.jpg", 0.5, lost,
                 lost_why=why)


# --- the pure parts -------------------------------------------------------------------------------------------

def test_summary_counts_and_says_the_misfit_once() -> None:
    s = RunSummary(ref_size=(64, 32))
    frame = Frame(0, "a", np.zeros((120, 160, 3), np.uint8))
    assert s.add(_match(0, True, "weak-view"), frame) == []           # a size alone is not said
    due = []
    for i in range(1, FIRST_STRETCH):
        due += s.add(_match(i, lost=i % 10 != 0, why="no-trajectory"), frame)
    assert len(due) == 1 and f"46 of the first {FIRST_STRETCH} frames lost" in due[0] and "64x32" in due[0]
    assert s.add(_match(99, True), frame) == []                        # each warning once
    s.skip()
    assert (s.frames, s.answered, sum(s.lost.values())) == (51, 4, 47)
    ended, counts = s.lines(10.2, "interrupted (Ctrl-C, SIGINT)")
    assert ended == "stream ended: interrupted (Ctrl-C, SIGINT)"
    assert counts == ("51 frames in 10.2 s (5.0 frames/s): 4 answered, 47 lost (no-trajectory 45, "
                      "no reason given 1, weak-view 1), 1 undecodable skipped")


def test_a_misfit_size_is_said_only_when_answers_suffer() -> None:
    frame = Frame(0, "a", np.zeros((720, 1280, 3), np.uint8))
    fine = RunSummary(ref_size=(160, 120))   # upscaled frames that still match: no word
    assert all(fine.add(_match(i, lost=i % 5 == 0), frame) == [] for i in range(2 * FIRST_STRETCH))
    poor = RunSummary(ref_size=(160, 120))
    due = [d for i in range(2 * FIRST_STRETCH) for d in poor.add(_match(i, lost=i % 3 != 0), frame)]
    assert due == ["33 of the first 50 frames lost, and frames are 1280x720 pixels, the map's references 160x120: "
                   "frames far from the references' size match less well (check that the camera and its resolution "
                   "are the ones the map was built from)"]


def test_a_fitting_stream_is_not_warned() -> None:
    s = RunSummary(ref_size=(160, 120))
    frame = Frame(0, "a", np.zeros((120, 160, 3), np.uint8))
    assert all(s.add(_match(i, lost=i % 2 == 0), frame) == [] for i in range(2 * FIRST_STRETCH))
    assert not size_misfit((320, 240), (160, 120)) and size_misfit((160, 120), (64, 32))
    assert size_misfit((640, 360), (640, 480)) and not size_misfit((640, 480), (600, 480))   # aspect ratios
    assert reference_size({"frame_size": [64, 32]}) == (64, 32)
    assert reference_size({"model_choice": "camera 160x120: efficientnet_lite0_stage5_160x120.onnx"}) == (160, 120)
    assert reference_size({"frame_size": "big"}) is None and reference_size({}) is None


def test_limits_stop_reading_the_source() -> None:
    read = []

    def source():
        for i in range(100):
            read.append(i)
            yield Frame(i, str(i), None, "x")

    limited = Limited(source(), max_frames=7)
    assert len(list(limited)) == 7 and read == list(range(7)) and str(limited.reason) == "max_frames 7"
    assert limited.reason.line(flag) == "--max-frames 7"   # the CLI's words
    now = [0.0]

    def clock() -> float:
        now[0] += 1.0
        return now[0]

    read.clear()
    timed = Limited(source(), duration=3.5, clock=clock)
    assert len(list(timed)) == 3 and timed.reason.line(flag) == "--duration 3.5 s"
    whole = Limited(iter([Frame(0, "a", None, "x")]), max_frames=5)
    assert len(list(whole)) == 1 and whole.reason is None


def test_the_log_is_a_log(tmp_path: Path) -> None:
    """Lines in NAME.part as they are written; the old NAME replaced only at the end; an early end keeps
    the lines; no line: nothing replaced; a second writer refused; a dead run's log recovered."""
    out = tmp_path / "run.csv"
    out.write_text("the last run\n")
    os.chmod(out, 0o640)
    log = ResultLog("csv", out)
    assert isinstance(log, ResultSink)
    for i in range(3):
        log.write(_match(i))
    assert part_path(out).read_text().count("\n") == 4 and out.read_text() == "the last run\n"
    with pytest.raises(VprError, match="another vpr-edge is writing it"):
        ResultLog("csv", out)
    log.close(complete=False)
    assert len(_rows(out)) == 3 and not part_path(out).exists() and (out.stat().st_mode & 0o777) == 0o640
    empty = ResultLog("jsonl", out)
    empty.close(complete=False)
    assert len(_rows(out)) == 3 and not part_path(out).exists()       # a run with no line replaces nothing
    part_path(out).write_text(",".join(FIELDS) + "\n0,a.jpg,,,,,,,,,,,0.1,,1,\n1,b.jp")   # killed mid-line
    again = ResultLog("jsonl", out)
    assert out.read_text().count("\n") == 2 and out.read_text().endswith("0.1,,1,\n")   # the dead run's, whole
    again.write(_match(5))
    again.close(True)
    assert [json.loads(x)["frame_index"] for x in out.read_text().splitlines()] == [5]


def test_a_failed_run_keeps_both(tmp_path: Path) -> None:
    """After a failure the older NAME stays byte for byte and the run's whole lines stay in NAME.part."""
    out = tmp_path / "run.jsonl"
    out.write_bytes(b"the last run\n")
    log = ResultLog("jsonl", out)
    for i in range(3):
        log.write(_match(i))
    os.write(log._fd, b'{"frame_index": 3, "na')        # the line a full disk cut short
    log.close(complete=False, failed=True)
    assert out.read_bytes() == b"the last run\n" and log.kept == str(part_path(out))
    assert [json.loads(x)["frame_index"] for x in part_path(out).read_text().splitlines()] == [0, 1, 2]


# --- real runs ------------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def ws(tmp_path_factory: pytest.TempPathFactory, small_refs: Path) -> Path:
    """A small map of the first 24 references, and a long stream: the sample's 111 query frames six times."""
    w = tmp_path_factory.mktemp("vehicle")
    proc = _run("build-map", small_refs, "-o", w / "map.npz", "--components", "4")
    assert proc.returncode == 0, proc.stderr
    (w / "long").mkdir()
    queries = sorted((sample_folder() / "query").glob("*.jpg"))
    for k in range(6):
        for f in queries:
            (w / "long" / f"{k}{f.name}").symlink_to(f)
    return w


def _lines_in(path: Path) -> int:
    try:
        return path.read_bytes().count(b"\n")
    except FileNotFoundError:
        return 0


@pytest.mark.slow
@pytest.mark.parametrize("sig, code, said", [(signal.SIGINT, 130, "interrupted (Ctrl-C, SIGINT)"),
                                             (signal.SIGTERM, 143, "terminated (SIGTERM)")])
def test_a_stopped_stream_keeps_its_lines(ws: Path, tmp_path: Path, sig: int, code: int, said: str) -> None:
    out = tmp_path / "run.csv"
    out.write_text("the last run\n")
    # Ctrl-C as a terminal delivers it, even where the tests run as a background job (whose children start
    # with SIGINT ignored, and a Python started so never raises KeyboardInterrupt)
    proc = subprocess.Popen([*CLI, "localize", "-m", str(ws / "map.npz"), "-s", str(ws / "long"), "-o", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    end = time.time() + 120
    while _lines_in(part_path(out)) < 21 and proc.poll() is None and time.time() < end:
        time.sleep(0.01)
    assert out.read_text() == "the last run\n"                          # replaced only once the run ends
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == code and "Traceback" not in err, err
    rows = _rows(out)
    assert 20 <= len(rows) < 666 and [int(r["frame_index"]) for r in rows] == list(range(len(rows)))
    assert f"stream ended: {said}" in err and f"{len(rows)} frames in" in err
    assert f"{len(rows)} lines kept in {out}" in err and not part_path(out).exists()


@pytest.mark.slow
def test_limits_end_a_stream_with_exit_0(ws: Path, tmp_path: Path) -> None:
    proc = _run("localize", "-m", ws / "map.npz", "-s", ws / "long", "-o", tmp_path / "a.csv", "--max-frames", 7)
    assert proc.returncode == 0 and len(_rows(tmp_path / "a.csv")) == 7, proc.stderr
    assert "stream ended: --max-frames 7" in proc.stderr and "7 frames in" in proc.stderr
    proc = _run("localize", "-m", ws / "map.npz", "-s", ws / "long", "-o", tmp_path / "b.jsonl", "--duration", 1)
    assert proc.returncode == 0 and "stream ended: --duration 1 s" in proc.stderr, proc.stderr
    lines = (tmp_path / "b.jsonl").read_text().splitlines()
    assert 0 < len(lines) < 666 and [json.loads(x)["frame_index"] for x in lines] == list(range(len(lines)))


@pytest.mark.slow
def test_a_stream_that_does_not_fit_the_map_is_said(ws: Path, tmp_path: Path, small_refs: Path) -> None:
    """Frames of 160x120 against a map of 64x32 references: said at the first frame and after the first 50,
    and the summary counts the lost frames by reason."""
    import cv2

    tiny = tmp_path / "tiny"
    tiny.mkdir()
    for f in sorted(small_refs.glob("*.jpg")):
        cv2.imwrite(str(tiny / f.name), cv2.resize(cv2.imread(str(f)), (64, 32)))
    assert _run("build-map", tiny, "-o", tmp_path / "tiny.npz", "--components", "4").returncode == 0
    proc = _run("localize", "-m", tmp_path / "tiny.npz", "-s", sample_folder() / "query", "-o", tmp_path / "o.csv")
    assert proc.returncode == 0, proc.stderr
    warnings = [ln for ln in proc.stderr.splitlines() if ln.startswith("vpr-edge: warning:")]
    assert any("frames are 160x120 pixels, the map's references 64x32" in w for w in warnings), proc.stderr
    assert any("of the first 50 frames lost: this stream hardly fits the map" in w for w in warnings), proc.stderr
    rows = _rows(tmp_path / "o.csv")
    lost = sum(r["lost"] == "1" for r in rows)
    assert "111 frames in" in proc.stderr and f"{111 - lost} answered, {lost} lost (" in proc.stderr
    assert _run("build-map", sample_folder() / "ref", "-o", tmp_path / "whole.npz", "--components", "4"
                ).returncode == 0
    fits = _run("localize", "-m", tmp_path / "whole.npz", "-s", sample_folder() / "query", "--max-frames", 60)
    assert fits.returncode == 0 and "warning" not in fits.stderr, fits.stderr


def test_a_closed_pipe_ends_quietly(ws: Path, small_queries: Path) -> None:
    """``localize | head -2``: exit 0, no traceback, no error line."""
    proc = subprocess.run(f"{sys.executable} -m vpr_edge localize -m {ws / 'map.npz'} -s {small_queries} | head -2;"
                          " exit ${PIPESTATUS[0]}", shell=True, executable="/bin/bash", capture_output=True,
                          text=True, timeout=300, env={k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"})
    assert proc.returncode == 0 and proc.stdout.count("\n") == 2, proc.stderr
    assert "Traceback" not in proc.stderr and "error" not in proc.stderr and "Exception" not in proc.stderr
    assert "stream ended: standard output closed by its reader" in proc.stderr


def test_a_full_disk_behind_buffered_stdout(ws: Path, small_queries: Path) -> None:
    if not Path("/dev/full").exists():
        pytest.skip("no /dev/full here")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
    with open("/dev/full", "w") as full:
        proc = subprocess.run([*CLI, "localize", "-m", str(ws / "map.npz"), "-s", str(small_queries)], stdout=full,
                              stderr=subprocess.PIPE, text=True, timeout=300, env=env)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr and "Exception" not in proc.stderr, proc.stderr
    assert proc.stderr.splitlines()[-1] == "vpr-edge: error: stdout: cannot write results (No space left on device)"


def test_bad_sources_and_maps_fail_before_any_output(ws: Path, tmp_path: Path, small_queries: Path) -> None:
    """An unopenable video and a map whose metadata names a front end its arrays do not fit: one line naming
    the file, exit 2, nothing on standard output."""
    video = tmp_path / "broken.mp4"
    video.write_bytes(b"\x00\x00\x00\x18ftypmp42 not really a video")
    proc = _run("localize", "-m", ws / "map.npz", "-s", video)
    assert proc.returncode == 2 and proc.stdout == "" and proc.stderr.count("\n") == 1, proc.stderr
    assert "broken.mp4: cannot open video" in proc.stderr
    with np.load(ws / "map.npz", allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(str(arrays.pop("__meta__")))
    meta["features"] = {"name": "hog", "params": {}}
    arrays["__meta__"] = np.array(json.dumps(meta))
    with open(tmp_path / "hog.npz", "wb") as f:
        np.savez(f, **arrays)
    proc = _run("localize", "-m", tmp_path / "hog.npz", "-s", small_queries, "-o", tmp_path / "o.csv")
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert "hog.npz: map is inconsistent (its metadata names the hog front end" in proc.stderr
    assert not (tmp_path / "o.csv").exists() and not part_path(tmp_path / "o.csv").exists()


def test_ground_truth_that_does_not_fit_the_map_is_refused_before_encoding(
        ws: Path, small_queries: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from typer.testing import CliRunner

    from vpr_edge.cli import app
    from vpr_edge.evaluation import sources

    gt = tmp_path / "gt.csv"
    gt.write_text("query,references\n" + "".join(f"{i},{i + 30}\n" for i in range(24)))   # the map has 24
    monkeypatch.setattr(sources, "from_map", lambda *a, **k: pytest.fail("frames encoded"))
    res = CliRunner().invoke(app, ["evaluate", "--map", str(ws / "map.npz"), "--queries", str(small_queries),
                                   "--gt", str(gt)])
    assert res.exit_code == 2, res.output
    assert "gt.csv: names reference 53 but the map has only 24 references" in res.stderr


def test_an_unwritable_home_is_not_written(ws: Path, small_queries: Path) -> None:
    """A service account whose HOME cannot be written (here not even a folder): no warning, no failure."""
    env = dict(os.environ, HOME="/dev/null")
    env.pop("MPLCONFIGDIR", None)
    env.pop("ORT_DISABLE_TELEMETRY", None)
    proc = subprocess.run([*CLI, "localize", "-m", str(ws / "map.npz"), "-s", str(small_queries), "--max-frames",
                           "3"], capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 0 and proc.stdout.count("\n") == 4, proc.stderr
    assert [ln for ln in proc.stderr.splitlines() if not ln.startswith("vpr-edge: ")] == [], proc.stderr
    code = "import os, vpr_edge; print(os.environ['MPLCONFIGDIR'], os.environ['ORT_DISABLE_TELEMETRY'])"
    where, telemetry = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                                      timeout=60).stdout.split()
    assert where.startswith(("/tmp", os.environ.get("TMPDIR", "/tmp"))) and telemetry == "1"


# --- two writers of one map, a writer killed ------------------------------------------------------------------

def _holder(out: Path) -> str:
    try:
        return (out.parent / f".{out.name}.lock").read_text().strip()
    except FileNotFoundError:
        return ""


@pytest.mark.slow
def test_two_builds_of_one_map_never_lose_one_silently(ws: Path, small_refs: Path, tmp_path: Path) -> None:
    """The second build of a map being built is refused in one line (exit 2) before its work; the first
    writes its map; a build killed with SIGKILL while holding the map leaves no map, no temporary file and no
    lock that stops the next build."""
    out = tmp_path / "m.npz"
    first = subprocess.Popen([*CLI, "build-map", str(sample_folder() / "ref"), "-o", str(out), "--components", "4"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    end = time.time() + 120
    while _holder(out) != str(first.pid) and first.poll() is None and time.time() < end:
        time.sleep(0.01)
    second = _run("build-map", small_refs, "-o", out, "--components", "4")
    held = first.poll() is None
    assert first.wait(timeout=300) == 0, first.stderr.read()
    if not held:
        pytest.skip("the first build ended before the second started (a fast machine)")
    assert second.returncode == 2 and second.stderr.count("\n") == 1, second.stderr
    assert f"m.npz: another vpr-edge is writing it (process {first.pid})" in second.stderr
    from vpr_edge.map import load_map

    assert len(load_map(out).names) == 111                             # the first build's map, whole
    out.unlink()
    killed = subprocess.Popen([*CLI, "build-map", str(sample_folder() / "ref"), "-o", str(out), "--components",
                               "4"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    while _holder(out) != str(killed.pid) and killed.poll() is None and time.time() < end + 120:
        time.sleep(0.01)
    killed.kill()
    killed.communicate(timeout=60)
    assert not out.exists()
    again = _run("build-map", small_refs, "-o", out, "--components", "4")
    assert again.returncode == 0 and len(load_map(out).names) == 24, again.stderr
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


def test_a_stream_that_fails_half_way_keeps_its_lines(ws: Path, small_queries: Path, tmp_path: Path, capsys) -> None:
    """A source that fails after 5 frames (a camera unplugged): the error is raised, the 5 lines are kept in
    NAME.part (a failure makes no NAME) and the summary says so."""
    from vpr_edge.api import Localizer
    from vpr_edge.cli.localize import run_stream
    from vpr_edge.frames.images import open_stream

    frames, _ = open_stream(small_queries)

    def failing():
        for i, frame in enumerate(frames):
            if i == 5:
                raise VprError("camera0: the camera stopped delivering frames")
            yield frame

    out = tmp_path / "run.csv"
    log = ResultLog("csv", out)
    with pytest.raises(VprError, match="camera stopped"):
        run_stream(Localizer(ws / "map.npz"), Limited(failing()), [log], log, RunSummary(), 1, None, "camera0")
    assert len(_rows(part_path(out))) == 5 and not out.exists()
    err = capsys.readouterr().err
    assert "stream ended: failed (the error below)" in err
    assert f"5 lines kept in {part_path(out)} (the run failed); {out} not made" in err


def test_ctrl_c_inside_an_image_read_is_still_ctrl_c(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """NumPy's file read hands a Ctrl-C on as a SystemError caused by it (``errors.ctrl_c``); the commands
    read it as Ctrl-C, so that localize exits 130 with its lines kept, not 1 with a traceback. A SystemError
    of its own stays one."""
    import typer

    from vpr_edge.cli.common import user_errors
    from vpr_edge.errors import ctrl_c, one_line_errors
    from vpr_edge.frames import images

    def interrupted(*args, **kwargs):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as e:
            raise SystemError("<built-in function fromfile> returned a result with an exception set") from e

    monkeypatch.setattr(np, "fromfile", interrupted)
    frame = tmp_path / "frame.jpg"
    with pytest.raises(SystemError) as raised:
        images.load_image(frame)
    assert isinstance(ctrl_c(raised.value), KeyboardInterrupt)
    assert one_line_errors("x", lambda: images.load_image(frame)) == 130
    with pytest.raises(typer.Exit) as ended:
        with user_errors():
            images.load_image(frame)
    assert ended.value.exit_code == 130
    own = SystemError("a bug")
    assert ctrl_c(own) is own
    with pytest.raises(SystemError):
        with user_errors():
            raise own


def _killed_mid_stream(ws: Path, args: list[str], part: Path) -> int:
    """Run localize on the long stream with ``args``; SIGKILL it half a second after ``part`` first grew past
    what its start wrote (a second of answers at least); the kill's time, ns since the epoch."""
    proc = subprocess.Popen([*CLI, "localize", "-m", str(ws / "map.npz"), "-s", str(ws / "long"), *args],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    end, start = time.time() + 120, None
    while proc.poll() is None and time.time() < end:
        size = part.stat().st_size if part.exists() else 0
        start = start if start is not None or not size else size
        if start is not None and size > start:
            break
        time.sleep(0.01)
    time.sleep(0.5)
    killed = time.time_ns()
    proc.kill()
    proc.wait(timeout=60)
    assert proc.returncode == -signal.SIGKILL, "the stream ended before the kill: make it longer"
    return killed


@pytest.mark.slow
def test_an_mcap_file_survives_a_sigkill(ws: Path, tmp_path: Path) -> None:
    """Killed mid-stream: mcap's own reader reads NAME.part's answers, in order, up to a second before the
    kill; the next run finalises it into NAME (with its summary) and says so."""
    pytest.importorskip("mcap")
    from mcap.reader import NonSeekingReader, make_reader

    from vpr_edge.outputs.mcap_record import ANSWER, recover

    out = tmp_path / "run.mcap"
    killed = _killed_mid_stream(ws, ["-o", str(out)], part_path(out))
    answers = []
    with open(part_path(out), "rb") as f:
        try:
            for _, channel, message in NonSeekingReader(f).iter_messages(log_time_order=False):
                if channel.topic == ANSWER:
                    answers.append(message)
        except Exception:   # noqa: BLE001 - the file ends where the kill cut it
            pass
    frames = [json.loads(m.data)["frame_index"] for m in answers]
    assert frames == list(range(len(frames))) and len(frames) >= 2
    assert answers[-1].publish_time >= killed - 1_000_000_000, (killed - answers[-1].publish_time) / 1e9
    kept = tmp_path / "kept.mcap"
    assert recover(part_path(out), kept).endswith(f"messages finalised as {kept}")
    with open(kept, "rb") as f:
        reader = make_reader(f)
        assert reader.get_summary() is not None
        again = [json.loads(m.data)["frame_index"] for _, c, m in reader.iter_messages() if c.topic == ANSWER]
        assert again == frames and [m.name for m in reader.iter_metadata()] == ["vpr-edge"]
    proc = _run("localize", "-m", ws / "map.npz", "-s", ws / "long", "-o", out, "--max-frames", "3")
    assert proc.returncode == 0 and f"finalised as {out}" in proc.stderr, proc.stderr
    assert not part_path(out).exists() and sorted(p.name for p in tmp_path.iterdir()) == ["kept.mcap", "run.mcap"]


@pytest.mark.slow
def test_a_rerun_recording_survives_a_sigkill(ws: Path, tmp_path: Path) -> None:
    """Killed mid-stream: Rerun's own reader reads NAME.part's frames, in order, up to a second before the
    kill; the next run makes it NAME and says so."""
    pytest.importorskip("rerun")
    import pyarrow as pa
    from rerun.chunk import RrdReader

    out = tmp_path / "run.rrd"
    killed = _killed_mid_stream(ws, ["--rerun", str(out)], part_path(out))
    rows = []
    for chunk in RrdReader(part_path(out)).stream():
        if chunk.entity_path == "/answer":
            batch = chunk.to_record_batch()
            cols = {n: c.cast(pa.int64()) if pa.types.is_temporal(c.type) else c
                    for n, c in zip(batch.schema.names, batch.columns)}
            rows += pa.table(cols).to_pylist()
    frames = sorted(r["frame"] for r in rows)
    assert frames == list(range(len(frames))) and len(frames) >= 2
    assert max(r["log_time"] for r in rows) >= killed - 1_000_000_000, (killed - max(r["log_time"] for r in rows)) / 1e9
    proc = _run("localize", "-m", ws / "map.npz", "-s", ws / "long", "--rerun", out, "--max-frames", "3")
    assert proc.returncode == 0 and f"made {out} as it is" in proc.stderr, proc.stderr
    assert not part_path(out).exists() and out.exists()


def test_a_map_beside_a_dead_writers_files_is_said(ws: Path, tmp_path: Path) -> None:
    """A map opened beside the lock and temporary file of a build-map that died (by info, by localize): one
    warning line (what, and that the next build removes them); beside a lock a live writer holds, or nothing:
    no word."""
    import fcntl
    import shutil

    out = tmp_path / "route.npz"
    shutil.copy(ws / "map.npz", out)
    quiet = _run("info", out)
    assert quiet.returncode == 0 and "warning" not in quiet.stderr, quiet.stderr
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    (tmp_path / f".route.npz.{dead.stdout.strip()}.abcdefgh.tmp").write_bytes(b"half a map")
    lock = tmp_path / ".route.npz.lock"
    lock.write_text("12345\n")
    said = _run("info", out)
    lines = [ln for ln in said.stderr.splitlines() if ln.startswith("vpr-edge: warning:")]
    assert said.returncode == 0 and len(lines) == 1, said.stderr
    assert f"{out}: 2 file(s) beside it left by a build-map that died" in lines[0] and "next build-map" in lines[0]
    ran = _run("localize", "-m", out, "-s", ws / "long", "--max-frames", "2", "-o", tmp_path / "run.csv")
    assert ran.returncode == 0 and [ln for ln in ran.stderr.splitlines() if "left by a build-map" in ln] == \
        lines, ran.stderr
    with open(lock) as held:                                           # a live writer's lock: not a leftover
        fcntl.flock(held.fileno(), fcntl.LOCK_EX)
        assert "1 file(s) beside it" in _run("info", out).stderr
