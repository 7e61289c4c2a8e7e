"""A recording reaches the system within ``FLUSH_INTERVAL_S`` of each answer, even while no frame comes (a
camera that stalls): what a kill then finds in ``NAME.part``, read with mcap's and Rerun's own readers while
the writer still runs. The cost of that flushing per frame: ``bench-outputs`` runs and prints its ratios."""
from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import pytest

from helpers import mcap_answer_frames

from vpr_edge.api import Match
from vpr_edge.map.drives import Drives
from vpr_edge.outputs.part import FLUSH_INTERVAL_S, part_path


def _map(n: int) -> SimpleNamespace:
    """What the sinks read of a map: its names, drives and positions (none)."""
    return SimpleNamespace(names=[f"{i:07d}.jpg" for i in range(n)], drives=Drives.single("ref", n, None),
                           positions=None)


def _answers(n: int) -> list[Match]:
    return [Match(i, f"q{i}.jpg", i, f"{i:07d}.jpg", 9.0 + i, False, None) for i in range(n)]


def _mcap_frames(part: Path) -> list[int]:
    """The answers' frame indices that mcap's reader finds in a recording still being written."""
    return mcap_answer_frames(part)


def _rrd_frames(part: Path) -> list[int]:
    """The answers' frame indices that Rerun's reader finds in a recording still being written."""
    import pyarrow as pa
    from rerun.chunk import RrdReader

    frames = []
    for chunk in RrdReader(part).stream():
        if chunk.entity_path == "/answer":
            batch = chunk.to_record_batch()
            frames += pa.table({n: c for n, c in zip(batch.schema.names, batch.columns)
                                if n == "frame"}).column("frame").to_pylist()
    return sorted(frames)


def _stalled(sink, part: Path, read) -> tuple[list[int], list[int]]:
    """Three answers, then no frame for ``FLUSH_INTERVAL_S`` and a little: what the part holds before the
    pause's end and after it."""
    for m in _answers(3):
        sink.write(m, None)
    start = time.monotonic()
    early = read(part)
    time.sleep(max(0.0, FLUSH_INTERVAL_S + 0.3 - (time.monotonic() - start)))
    return early, read(part)


def test_a_stalled_mcap_stream_reaches_the_disk_within_the_interval(tmp_path: Path) -> None:
    pytest.importorskip("mcap")
    from vpr_edge.outputs.mcap_record import McapSink

    out = tmp_path / "run.mcap"
    sink = McapSink(out, _map(5))
    try:
        _, late = _stalled(sink, part_path(out), _mcap_frames)
    finally:
        sink.close(True)
    assert late == [0, 1, 2]
    assert not part_path(out).exists() and len(_mcap_frames(out)) == 3


def test_a_stalled_rerun_stream_reaches_the_disk_within_the_interval(tmp_path: Path) -> None:
    pytest.importorskip("rerun")
    from vpr_edge.outputs.view import RerunSink

    out = tmp_path / "run.rrd"
    sink = RerunSink(_map(5), tmp_path / "m.npz", record=out, stream="stalled")
    try:
        _, late = _stalled(sink, part_path(out), _rrd_frames)
    finally:
        sink.close(True)
    assert late == [0, 1, 2]
    assert not part_path(out).exists() and _rrd_frames(out) == [0, 1, 2]


def test_a_write_error_of_the_flushing_thread_is_said_at_the_next_answer(tmp_path: Path) -> None:
    """A flush that fails between frames (a full disk) fails the next write in one line naming the part."""
    pytest.importorskip("mcap")
    from vpr_edge.errors import VprError
    from vpr_edge.outputs.mcap_record import McapSink

    out = tmp_path / "run.mcap"
    sink = McapSink(out, _map(5))
    sink.write(_answers(1)[0], None)
    sink._flusher.error = OSError(28, "No space left on device")
    with pytest.raises(VprError, match=r"run\.mcap\.part: cannot write results \(No space left on device\)"):
        sink.write(_answers(2)[1], None)
    sink.close(False, failed=True)
    assert part_path(out).exists() and not out.exists()


@pytest.mark.slow
def test_bench_outputs_prints_ratios(tmp_path: Path) -> None:
    """``python -m vpr_edge_bench bench-outputs`` on a short stream: a row per output, ratios to the CSV's."""
    proc = subprocess.run([sys.executable, "-m", "vpr_edge_bench", "bench-outputs", "--frames", "12",
                           "--repeat", "1", "--threads", "1"], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    rows = {ln.split()[0]: ln.split() for ln in proc.stdout.splitlines() if ln.split()[:1] and
            ln.split()[0] in ("csv", "mcap", "mcap-unflushed", "rrd", "rrd-unflushed")}
    assert set(rows) == {"csv", "mcap", "mcap-unflushed", "rrd", "rrd-unflushed"}, proc.stdout
    assert float(rows["csv"][-1]) == 1.0 and all(float(r[-1]) > 0 for r in rows.values())
