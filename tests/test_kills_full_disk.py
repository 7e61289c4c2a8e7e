"""A disk that fills under ``localize -o run.mcap``: the older file byte for byte, and the run's answers in
``NAME.part``, read back with mcap's own reader, in order from the first frame (a small tmpfs: root only)."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from helpers import mcap_answer_frames

CLI = [sys.executable, "-m", "vpr_edge"]


@pytest.mark.slow
def test_a_full_disk_keeps_the_older_mcap_and_the_answers_in_its_part(tmp_path: Path, small_refs: Path,
                                                                       small_queries: Path) -> None:
    pytest.importorskip("mcap")

    proc = subprocess.run([*CLI, "build-map", small_refs, "-o", tmp_path / "m.npz", "--components", "4"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    disk = tmp_path / "disk"
    disk.mkdir()
    if os.geteuid() != 0 or subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(disk)],
                                           capture_output=True).returncode != 0:
        pytest.skip("a small tmpfs needs root (mount)")
    try:
        out = disk / "run.mcap"
        older = b"an older, complete recording\n" * 500
        out.write_bytes(older)
        (disk / "filler").write_bytes(b"x" * (64 * 1024 - len(older) - 8 * 1024))
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
    finally:
        subprocess.run(["umount", str(disk)], check=True)
        shutil.rmtree(disk, ignore_errors=True)
