"""Shared fixtures: the bundled sample (real Corridor frames), the bundled default model and a small disk that
fills."""
from __future__ import annotations

import os
import shutil
import subprocess
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from vpr_edge.resources import sample_folder

ROOT = Path(__file__).resolve().parent.parent
SAMPLE = sample_folder("corridor")   # the bundled sample, inside the package


@pytest.fixture(scope="session")
def model_path() -> Path:
    from vpr_edge.features.cnn import default_model_path

    return default_model_path()


def _first_frames(factory: pytest.TempPathFactory, sub: str, n: int = 24) -> Path:
    folder = factory.mktemp(sub)
    for f in sorted((SAMPLE / sub).glob("*.jpg"))[:n]:
        shutil.copy(f, folder / f.name)
    return folder


@pytest.fixture(scope="session")
def small_refs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The first 24 real reference frames of the bundled sample, in a folder of their own."""
    return _first_frames(tmp_path_factory, "ref")


@pytest.fixture(scope="session")
def small_queries(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The first 24 real query frames of the bundled sample."""
    return _first_frames(tmp_path_factory, "query")


SMALL_DISK = 64 * 1024   # bytes: the tmpfs of ``full_disk``
ROOM = 8 * 1024          # bytes ``full_disk`` leaves free


@pytest.fixture()
def full_disk(tmp_path: Path) -> Iterator[Callable[[str, bytes], Path]]:
    """A small tmpfs (``SMALL_DISK``) mounted at ``tmp_path / "disk"`` (root only: the test skips elsewhere),
    unmounted after; called with (NAME, OLDER) it writes OLDER to the disk's NAME and fills the disk to leave
    ``ROOM`` free -> that file's path."""
    disk = tmp_path / "disk"
    disk.mkdir()
    if os.geteuid() != 0 or subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={SMALL_DISK // 1024}k", "tmpfs",
                                            str(disk)], capture_output=True).returncode != 0:
        pytest.skip("a small tmpfs needs root (mount)")

    def fill(name: str, older: bytes) -> Path:
        (disk / name).write_bytes(older)
        (disk / "filler").write_bytes(b"x" * (SMALL_DISK - len(older) - ROOM))
        return disk / name

    try:
        yield fill
    finally:
        subprocess.run(["umount", str(disk)], check=True)
        shutil.rmtree(disk, ignore_errors=True)
