"""A disk that fills under ``localize -o run.mcap``: the older file byte for byte, and the run's answers in
``NAME.part``, read back with mcap's own reader, in order from the first frame (a small tmpfs: root only)."""
from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from helpers import mcap_answer_frames

CLI = [sys.executable, "-m", "vpr_edge"]


@pytest.mark.slow
def test_a_full_disk_keeps_the_older_mcap_and_the_answers_in_its_part(tmp_path: Path, small_refs: Path,
                                                                       small_queries: Path,
                                                                       full_disk: Callable[[str, bytes], Path]) -> None:
    pytest.importorskip("mcap")

    proc = subprocess.run([*CLI, "build-map", small_refs, "-o", tmp_path / "m.npz", "--components", "4"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    older = b"an older, complete recording\n" * 500
    out = full_disk("run.mcap", older)
    queries = tmp_path / "queries"                                  # a stream longer than the room
    queries.mkdir()
    for i, f in enumerate(sorted(small_queries.iterdir()) * 40):
        (queries / f"{i:07d}{f.suffix}").symlink_to(f)
    proc = subprocess.run([*CLI, "localize", "-m", tmp_path / "m.npz", "-s", queries, "-o", out],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("vpr-edge: error:")]
    assert len(errors) == 1 and "No space left on device" in errors[0] and f"{out}.part" in errors[0]
    assert f"{out}.part: the recording of a run that failed; {out} left as it was" in proc.stderr
    assert out.read_bytes() == older
    frames = mcap_answer_frames(f"{out}.part")
    assert frames == list(range(len(frames))) and len(frames) > 10, frames
