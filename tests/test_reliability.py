"""What a fleet operator does to the tool, with real processes: links and special files as outputs, SIGTERM and
SIGKILL in the middle of a write, two writers of one map at once, a closed standard output."""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from vpr_edge.map import load_map
from vpr_edge.resources import sample_folder

CLI = [sys.executable, "-m", "vpr_edge"]


def _run(*args: str, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([*CLI, *map(str, args)], capture_output=True, text=True, timeout=300, **kw)


def _temps(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.endswith(".tmp"))


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory, small_refs: Path) -> Path:
    """A small map of the first 24 references (4-component codebook), kept as the workspace's map."""
    w = tmp_path_factory.mktemp("rel")
    proc = _run("build-map", small_refs, "-o", w / "map.npz", "--components", "4", "--save-codebook", w / "cb.npz")
    assert proc.returncode == 0, proc.stderr
    return w


@pytest.mark.slow
def test_symbolic_link_output_is_written_through(built: Path, small_queries: Path, tmp_path: Path) -> None:
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "run42.csv").write_text("old\n")
    (tmp_path / "latest.csv").symlink_to("data/run42.csv")
    proc = _run("localize", "-m", built / "map.npz", "-s", small_queries, "-o", tmp_path / "latest.csv")
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "latest.csv").is_symlink() and os.readlink(tmp_path / "latest.csv") == "data/run42.csv"
    assert (tmp_path / "data" / "run42.csv").read_text().count("\n") == 25     # header + 24 frames
    assert not _temps(tmp_path) and not _temps(tmp_path / "data")


@pytest.mark.slow
def test_special_file_output_is_written_in_place(built: Path, small_queries: Path) -> None:
    proc = _run("localize", "-m", built / "map.npz", "-s", small_queries, "-o", "/dev/stdout", "--format", "csv")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.count("\n") == 25 and proc.stdout.startswith("frame_index,")
    assert os.path.islink("/dev/stdout") or not os.path.exists("/dev/stdout") or \
        not os.path.isfile("/dev/stdout")                                   # never replaced by a file
    assert _run("evaluate", "--similarity", built / "nope.npy", "--gt", "/dev/null", "--json", "/dev/null"
                ).returncode == 2                                            # /dev/null is writable, no alias


def test_closed_stdout_is_one_line(built: Path, small_queries: Path) -> None:
    for args in (["info", built / "map.npz"], ["localize", "-m", built / "map.npz", "-s", small_queries],
                 ["--version"]):
        proc = subprocess.run([*CLI, *map(str, args)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                              text=True, timeout=300, preexec_fn=lambda: os.close(1))
        assert proc.returncode == 2, (args, proc.stderr)
        assert proc.stderr.count("\n") == 1 and "standard output is closed" in proc.stderr, proc.stderr


def _start_build(refs: Path, out: Path, *extra: str) -> subprocess.Popen:
    return subprocess.Popen([*CLI, "build-map", str(refs), "-o", str(out), *extra], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def _wait_for_work(proc: subprocess.Popen, timeout: float = 120.0) -> None:
    """Until the process has loaded onnxruntime (its imports done, the signal handlers installed: a busy
    machine can take seconds to import), or has ended."""
    end = time.time() + timeout
    while proc.poll() is None and time.time() < end:
        try:
            if "onnxruntime" in Path(f"/proc/{proc.pid}/maps").read_text():
                return
        except OSError:
            return
        time.sleep(0.05)


@pytest.mark.slow
def test_sigterm_ends_a_build_cleanly(built: Path, tmp_path: Path) -> None:
    shutil.copy(built / "map.npz", tmp_path / "map.npz")
    before = (tmp_path / "map.npz").read_bytes()
    proc = _start_build(sample_folder() / "ref", tmp_path / "map.npz", "--components", "4")
    _wait_for_work(proc)
    time.sleep(0.5)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    if proc.returncode == 0:
        pytest.skip("the build finished before the signal (a fast machine)")
    assert proc.returncode == 143 and err.strip().endswith("vpr-edge: terminated"), (proc.returncode, err)
    assert "Traceback" not in err
    assert (tmp_path / "map.npz").read_bytes() == before and not _temps(tmp_path)


@pytest.mark.slow
def test_sigkill_at_any_moment_leaves_the_old_or_the_new_map(built: Path, tmp_path: Path) -> None:
    """Kill a build of the whole sample at several moments: the map is always a complete one (old or new);
    the next writer removes the dead writers' temporary files."""
    out = tmp_path / "map.npz"
    shutil.copy(built / "map.npz", out)
    old_names = load_map(built / "map.npz").names
    new_names = sorted(p.name for p in (sample_folder() / "ref").glob("*.jpg"))
    for delay in (0.5, 2.0, 4.0):                      # while loading the model, extracting, fitting
        proc = _start_build(sample_folder() / "ref", out, "--components", "4", "--storage", "float32")
        time.sleep(delay)
        proc.kill()
        proc.communicate(timeout=60)
        assert load_map(out).names in (old_names, new_names)
    left_behind = 0
    for _ in range(3):                                 # while writing: killed as soon as its temporary file exists
        proc = _start_build(sample_folder() / "ref", out, "--components", "4", "--storage", "float32")
        while proc.poll() is None and not _temps(tmp_path):
            time.sleep(0.0005)
        proc.kill()
        proc.communicate(timeout=60)
        assert load_map(out).names in (old_names, new_names)
        left_behind += len(_temps(tmp_path))
    (tmp_path / ".map.npz.99999999.x.tmp").write_bytes(b"a dead writer's")   # a PID no process has
    proc = _start_build(sample_folder() / "ref", out, "--components", "4")
    assert proc.wait(timeout=300) == 0, proc.stderr.read()
    assert len(load_map(out).names) == 111 and not _temps(tmp_path)
    assert left_behind > 0, "no kill landed during a write"


@pytest.mark.slow
def test_two_appends_at_once_keep_both(built: Path, tmp_path: Path) -> None:
    refs = sorted((sample_folder() / "ref").glob("*.jpg"))
    for name, part in (("a", refs[30:50]), ("b", refs[60:80])):
        (tmp_path / name).mkdir()
        for f in part:
            shutil.copy(f, tmp_path / name / f.name)
    shutil.copy(built / "map.npz", tmp_path / "map.npz")
    first = load_map(tmp_path / "map.npz").names
    procs = [_start_build(tmp_path / name, tmp_path / "map.npz", "--append") for name in ("a", "b")]
    for p in procs:
        assert p.wait(timeout=300) == 0, p.stderr.read()
    names = load_map(tmp_path / "map.npz").names
    a, b = [f.name for f in refs[30:50]], [f.name for f in refs[60:80]]
    assert names in (first + a + b, first + b + a)
    assert not _temps(tmp_path)


def test_a_full_disk_names_the_file_and_leaves_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import errno

    import numpy as np

    import vpr_edge.files.npz as npz
    from vpr_edge.errors import os_error_line

    (tmp_path / "m.npz").write_bytes(b"the previous map")

    def full(*args, **kw) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(npz.np, "savez", full)
    with pytest.raises(OSError) as e:
        npz.write_npz(tmp_path / "m.npz", {"a": np.zeros(3)}, {"kind": "map"})
    assert os_error_line(e.value) == f"{tmp_path / 'm.npz'}: No space left on device"
    assert (tmp_path / "m.npz").read_bytes() == b"the previous map" and not _temps(tmp_path)


def test_writer_lock_serialises_two_writers(tmp_path: Path) -> None:
    """A second process asking for a map's writer lock waits until the first lets go (and says so)."""
    from vpr_edge.files.one_writer import writer_lock

    code = ("import sys, time; from vpr_edge.files.one_writer import writer_lock\n"
            "with writer_lock(sys.argv[1]):\n    print('got', time.time(), flush=True)\n")
    with writer_lock(tmp_path / "m.npz"):
        waiting = subprocess.Popen([sys.executable, "-c", code, str(tmp_path / "m.npz")], stdout=subprocess.PIPE,
                                   stderr=subprocess.PIPE, text=True)
        said = _stderr_until(waiting, "waiting for it to finish", seconds=300)   # slow starts (QEMU) included
        assert "another vpr-edge is writing it" in said, said
        time.sleep(0.5)
        assert waiting.poll() is None                     # still waiting while this process holds the lock
        released = time.time()
    out, err = waiting.communicate(timeout=300)
    assert waiting.returncode == 0 and float(out.split()[1]) >= released, (out, said + err)


def _stderr_until(process: subprocess.Popen, text: str, seconds: float) -> str:
    """What ``process`` writes on stderr up to the first ``text`` (all of it if it ends or ``seconds`` pass
    first): waits on what the process says, not on a guess of how long it takes to start."""
    import select

    said, fd, deadline = b"", process.stderr.fileno(), time.monotonic() + seconds
    while text.encode() not in said and time.monotonic() < deadline:
        ready, _, _ = select.select([fd], [], [], max(0.0, deadline - time.monotonic()))
        chunk = os.read(fd, 65536) if ready else b""
        if not chunk:
            break
        said += chunk
    return said.decode(errors="replace")


def test_outputs_at_the_name_limit_and_fifos(tmp_path: Path) -> None:
    """A legal 250-byte output name (multi-byte characters included) is written: its temporary file's and
    lock's names stay within 255 bytes; a dead writer's temporary file of that name is found and removed.
    A FIFO given as an output is refused at once (opening it would wait for a reader)."""
    import stat

    from vpr_edge.errors import VprError
    from vpr_edge.files.atomic import atomic_output
    from vpr_edge.files.checks import check_writable
    from vpr_edge.files.one_writer import writer_lock
    from vpr_edge.files.temps import remove_stale_temps, temp_stem

    name = "é" * 120 + "x" * 6 + ".npz"                       # 240 + 6 + 4 = 250 bytes
    assert len(name.encode()) == 250
    target = tmp_path / name
    seen = []
    with writer_lock(target), atomic_output(target) as tmp:
        seen = [p.name for p in tmp_path.iterdir()]
        tmp.write_bytes(b"data")
    assert target.read_bytes() == b"data" and all(len(os.fsencode(n)) <= 255 for n in seen)
    dead = tmp_path / f".{temp_stem(target)}.999999999.abcdefgh.tmp"   # no such process
    dead.write_bytes(b"left by kill -9")
    assert remove_stale_temps(target) == [dead] and not dead.exists() and target.exists()
    fifo = tmp_path / "out.fifo"
    os.mkfifo(fifo)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    with pytest.raises(VprError, match="out.fifo: a FIFO, socket or device"):
        check_writable(fifo)
    check_writable("/dev/null")                               # still an output, written in place


@pytest.mark.slow
def test_file_names_that_are_not_utf8(tmp_path: Path, small_queries: Path, small_refs: Path) -> None:
    """Frames and references named in another encoding (the bytes ``caf\\xe9``): read, matched, written to CSV
    and JSON lines and named in messages with such bytes as ``\\xNN``, never a failure of the error path."""
    import csv
    import json

    refs, frames = Path(os.fsdecode(bytes(tmp_path) + b"/r\xe9fs")), tmp_path / "frames"
    shutil.copytree(small_refs, refs)
    shutil.copytree(small_queries, frames)
    os.rename(os.fsencode(refs / "0000003.jpg"), os.fsencode(refs) + b"/caf\xe9.jpg")
    os.rename(os.fsencode(frames / "0000005.jpg"), os.fsencode(frames) + b"/0000005 caf\xe9.jpg")
    (frames / os.fsdecode(b"0000009 z\xe9.jpg")).write_bytes(b"not an image")
    m = tmp_path / "m.npz"
    assert _run("build-map", refs, "-o", m, "--components", "2").returncode == 0
    proc = _run("localize", "-m", m, "-s", frames, "-o", tmp_path / "out.csv")
    assert proc.returncode == 0, proc.stderr
    assert "0000009 z\\xe9.jpg: cannot decode" in proc.stderr and "Traceback" not in proc.stderr
    rows = list(csv.DictReader((tmp_path / "out.csv").open(encoding="utf-8")))
    assert "0000005 caf\\xe9.jpg" in [r["frame"] for r in rows] and len(rows) == 24   # the bad one skipped
    js = _run("localize", "-m", m, "-s", frames, "--format", "jsonl")
    assert js.returncode == 0 and len([json.loads(line) for line in js.stdout.splitlines()]) == 24
    bad = _run("build-map", frames, "-o", tmp_path / "n.npz", "--components", "2")
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "z\\xe9.jpg: cannot decode" in bad.stderr


def test_a_replaced_output_keeps_its_mode_and_dead_writers_temps_go(tmp_path: Path, capsys) -> None:
    """Writing over a file keeps its mode (0444 stays 0444, 0640 stays 0640) where the user may write it,
    and one the user may not write is refused as cp refuses it (root may: cp does too); a dead writer's
    temporary file is removed and said."""
    import stat

    from vpr_edge.errors import VprError
    from vpr_edge.files.atomic import atomic_output
    from vpr_edge.files.temps import temp_stem

    for mode in (0o640, 0o444):
        target = tmp_path / f"m{mode:o}.npz"
        target.write_bytes(b"old")
        os.chmod(target, mode)
        if os.access(target, os.W_OK):
            with atomic_output(target) as tmp:
                tmp.write_bytes(b"new")
            assert target.read_bytes() == b"new" and stat.S_IMODE(target.stat().st_mode) == mode
        else:
            with pytest.raises(VprError, match=f"m{mode:o}.npz: write-protected"):
                with atomic_output(target) as tmp:
                    tmp.write_bytes(b"new")
            assert target.read_bytes() == b"old"
    target = tmp_path / "route.npz"
    dead = tmp_path / f".{temp_stem(target)}.999999999.abcdefgh.tmp"
    dead.write_bytes(b"left by kill -9")
    with atomic_output(target) as tmp:
        tmp.write_bytes(b"map")
    assert not dead.exists() and "removed 1 temporary file(s) left by writers that died" in capsys.readouterr().err


def test_a_writer_killed_mid_write_leaves_a_temp_the_next_writer_removes(tmp_path: Path) -> None:
    """A writer killed with SIGKILL while its output is half written (a real process, killed for real) leaves
    its temporary file and the old map untouched; the next writer of that map removes the temporary file,
    says so, and writes; nothing else in the folder is touched."""
    target = tmp_path / "route.npz"
    target.write_bytes(b"the old map")
    (tmp_path / "other.tmp").write_bytes(b"not ours")
    code = ("import sys, time\nfrom vpr_edge.files.atomic import atomic_output\n"
            "with atomic_output(sys.argv[1]) as tmp:\n"
            "    tmp.write_bytes(b'half a map')\n    print('writing', flush=True)\n    time.sleep(60)\n")
    proc = subprocess.Popen([sys.executable, "-c", code, str(target)], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "writing"
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    left = [p for p in tmp_path.iterdir() if p.name.startswith(".route.npz.")]
    assert len(left) == 1 and target.read_bytes() == b"the old map"
    again = subprocess.run([sys.executable, "-c", "import sys\nfrom vpr_edge.files.atomic import atomic_output\n"
                            "with atomic_output(sys.argv[1]) as tmp:\n    tmp.write_bytes(b'new map')\n",
                            str(target)], capture_output=True, text=True, timeout=60)
    assert again.returncode == 0 and "removed 1 temporary file(s) left by writers that died" in again.stderr
    assert not left[0].exists() and target.read_bytes() == b"new map" and (tmp_path / "other.tmp").exists()
