"""``python -m vpr_edge_bench adapt-halves``: the halves share no place, adapting on one half helps the other
where the query frames share a nuisance (planted encodings, through the experiment's own ``adapt_and_score``),
a half too short to learn from is refused in one line, and the command runs on real frames."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import invoke

from vpr_edge.map.adapt import LabelledDrive
from vpr_edge.map.io import load_map
from vpr_edge.resources import sample_folder
from vpr_edge_bench.experiments.adapt_halves import adapt_and_score, split_halves
from vpr_edge_bench.streams import derive_streams

ROOT = Path(__file__).resolve().parent.parent
PLACES, DIM, SIGNAL = 160, 32, 24


@pytest.mark.parametrize("places", [100, 101, 7])
@pytest.mark.parametrize("learn_half", ["first", "second"])
def test_the_halves_share_no_place_and_cover_the_route(places: int, learn_half: str) -> None:
    (llo, lhi), (tlo, thi) = split_halves(places, learn_half)
    learned, tested = set(range(llo, lhi)), set(range(tlo, thi))
    assert not learned & tested and learned | tested == set(range(places))
    assert (llo == 0) == (learn_half == "first") and abs(len(learned) - len(tested)) <= 1


def _csv(path: Path, places: range) -> Path:
    path.write_text("query,references\n" + "".join(f"{i},{p}\n" for i, p in enumerate(places)))
    return path


def test_adapting_on_one_half_helps_the_other_where_queries_share_a_nuisance(tmp_path: Path) -> None:
    """Each place a direction in SIGNAL dims; every query frame also carries a strong random mix of the same
    four directions (a season the references lack): learned on the first half, suppressed on the second."""
    rng = np.random.default_rng(0)
    place = np.hstack([rng.normal(size=(PLACES, SIGNAL)), np.zeros((PLACES, DIM - SIGNAL))])
    nuisance = np.linalg.qr(rng.normal(size=(DIM, 4)))[0].T   # (4, DIM) orthonormal, shared by every query
    refs = place + 0.3 * rng.normal(size=place.shape)
    queries = place + 0.3 * rng.normal(size=place.shape) + (6.0 * rng.normal(size=(PLACES, 4)) + 1.0) @ nuisance
    np.save(tmp_path / "refs.npy", refs.astype(np.float32))
    half = PLACES // 2
    np.save(tmp_path / "learn.npy", queries[:half].astype(np.float32))
    np.save(tmp_path / "test.npy", queries[half:].astype(np.float32))
    code, _, err = invoke("build-map", tmp_path / "refs.npy", "-o", tmp_path / "map.npz")
    assert code == 0, err
    halves = split_halves(PLACES, "first")
    assert halves == ((0, half), (half, PLACES))
    scores = adapt_and_score(tmp_path / "map.npz",
                             LabelledDrive(str(tmp_path / "learn.npy"), str(_csv(tmp_path / "learn.csv", range(half)))),
                             tmp_path / "test.npy", _csv(tmp_path / "test.csv", range(half)), halves, tmp_path,
                             rank=4)
    assert len(scores) == 2 * 2 * 3 and all(0 <= x <= 1 for row in scores.values() for x in row)
    for std in (False, True):
        plain, adapted = scores["plain", std, 0][0], scores["adapted", std, 0][0]
        assert adapted > plain + 0.3 and adapted > 0.8, (std, plain, adapted)
        assert scores["adapted", std, 0][2] > scores["plain", std, 0][2] + 0.1   # the stream matcher's mapped right
    assert load_map(tmp_path / "adapted.npz").meta["adapted"]["pairs"] == half   # learned on one half only
    for kind in ("plain", "adapted"):
        cut = load_map(tmp_path / f"test.{kind}.npz")
        assert len(cut.names) == half and (cut.adaptation is not None) == (kind == "adapted")
    np.testing.assert_array_equal(load_map(tmp_path / "test.adapted.npz").stored.dense(),
                                  load_map(tmp_path / "adapted.npz").stored.dense()[half:])


def bench(*args: object) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "vpr_edge_bench", *map(str, args)], capture_output=True,
                          text=True, timeout=300, cwd=ROOT)


def streams_of(folder: Path, places: int) -> Path:
    """A derived-streams folder of the sample's first ``places`` frames (ref/, aligned/) and its map.npz."""
    derive_streams(sample_folder("corridor"), folder, ["aligned"], places)
    code, _, err = invoke("build-map", folder / "ref", "-o", folder / "map.npz")
    assert code == 0, err
    return folder


def test_a_half_under_fifty_frames_is_refused_in_one_line(tmp_path: Path) -> None:
    proc = bench("adapt-halves", "--streams", streams_of(tmp_path / "s", 60), "--work", tmp_path / "w")
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("adapt-halves: error:")]
    assert proc.returncode == 2 and "Traceback" not in proc.stderr and len(errors) == 1, proc.stderr
    assert "a half of 30 frames, too short to learn from (at least 50)" in errors[0]
    assert not (tmp_path / "w").exists()   # refused before anything is written


@pytest.mark.slow   # adapt-halves fits four maps on real frames: minutes under arm64 emulation
def test_it_runs_on_real_frames_learning_and_testing_apart(tmp_path: Path) -> None:
    streams = streams_of(tmp_path / "s", 100)
    proc = bench("adapt-halves", "--streams", streams, "--work", tmp_path / "w")
    assert proc.returncode == 0, proc.stderr
    rows = [ln.split(" | ") for ln in proc.stdout.splitlines() if ln.startswith(("| plain", "| adapted"))]
    assert [(r[0].strip("| "), r[1], r[2]) for r in rows] == [
        (kind, cos, str(t)) for kind in ("plain", "adapted") for cos in ("raw", "standardised") for t in (0, 1, 2)]
    assert all(0 <= float(x.strip(" |")) <= 1 for r in rows for x in r[3:])
    assert "learned on places 0-49 (50 frames); tested on places 50-99 (50 frames" in proc.stdout
    assert "codebook gains" in proc.stdout   # an IFV map: its gains are learned too
    ad = load_map(tmp_path / "w" / "adapted.npz").adaptation
    assert ad is not None and ad.gain_in is not None and ad.gain_out is not None
    aligned = sorted((streams / "aligned").iterdir())
    learned = [p.resolve() for p in sorted((tmp_path / "w" / "learn").iterdir())]
    tested = [p.resolve() for p in sorted((tmp_path / "w" / "test").iterdir())]
    assert learned == [p.resolve() for p in aligned[:50]]
    assert tested == [p.resolve() for p in aligned[50:]] and not set(learned) & set(tested)
    names = list(load_map(streams / "map.npz").names)
    assert list(load_map(tmp_path / "w" / "test.plain.npz").names) == names[50:]
