"""Shared fixtures: the bundled sample (real Corridor frames) and the bundled default model."""
from __future__ import annotations

import shutil
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
