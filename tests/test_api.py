"""The embedding API: ``Localizer`` pushes frames through the same chain as ``vpr-edge localize``."""
from __future__ import annotations

import csv
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from vpr_edge import Localizer
from vpr_edge.errors import VprError
from vpr_edge.frames.images import load_image, open_stream
from vpr_edge.matchers import get_matcher, stillness


@pytest.fixture(scope="module")
def api_map(tmp_path_factory: pytest.TempPathFactory, small_refs: Path) -> Path:
    out = tmp_path_factory.mktemp("api") / "m.npz"
    proc = subprocess.run([sys.executable, "-m", "vpr_edge", "build-map", str(small_refs), "-o", str(out),
                           "--components", "4", "--pca-dim", "0"], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    return out


@pytest.mark.slow
def test_push_matches_the_cli(api_map: Path, small_queries: Path) -> None:
    loc = Localizer(api_map, threads=1)
    files = sorted(small_queries.iterdir())
    pushed = [loc.push(load_image(f), f.name) for f in files]
    proc = subprocess.run([sys.executable, "-m", "vpr_edge", "localize", "-m", str(api_map), "-s",
                           str(small_queries)], capture_output=True, text=True, timeout=600)
    rows = list(csv.DictReader(proc.stdout.splitlines()))
    assert [m.ref_index for m in pushed] == [int(r["ref_index"]) if r["ref_index"] else None for r in rows]
    np.testing.assert_allclose([m.score for m in pushed], [float(r["score"]) for r in rows], atol=1e-5)
    assert [m.frame_index for m in pushed] == list(range(24)) and pushed[5].frame == files[5].name
    # reset: a new drive starts from no hypothesis and gives the same answers again
    loc.reset()
    again = [loc.push(load_image(f)).ref_index for f in files]
    assert again == [m.ref_index for m in pushed]


@pytest.mark.slow
def test_run_offline_mode_and_push_refused(api_map: Path, small_queries: Path) -> None:
    loc = Localizer(api_map, mode="dtw")
    frames, _ = open_stream(small_queries)
    out = list(loc.run(frames, batch_size=8))
    assert len(out) == 24 and np.mean([abs(m.ref_index - m.frame_index) <= 2 for m in out]) > 0.9
    with pytest.raises(ValueError, match="offline"):
        loc.push(np.zeros((120, 160, 3), np.uint8))


def test_bad_frames_and_options(api_map: Path) -> None:
    loc = Localizer(api_map, mode="single", min_confidence=2.0)          # cosine never reaches 2: all lost
    m = loc.push(np.full((120, 160, 3), 128, np.uint8))
    assert m.lost and m.ref_index is None and m.ref is None and m.x is None and m.along_m is None
    for bad in (np.zeros((120, 160), np.uint8), np.zeros((120, 160, 3), np.float32), np.zeros((4, 4, 3), np.uint8)):
        with pytest.raises(VprError, match="RGB uint8"):
            loc.push(bad)
    with pytest.raises(ValueError, match="unknown matcher"):
        Localizer(api_map, mode="nope")
    with pytest.raises(ValueError, match="no parameter"):
        Localizer(api_map, params={"nope": 1})
    with pytest.raises(VprError, match="no such file"):
        Localizer(api_map.with_name("missing.npz"))


def test_a_labelled_drives_line_sets_the_target_precision_of_any_mode(api_map: Path, tmp_path: Path) -> None:
    """With a calibration, ``target_precision`` is the line of any mode: the score its drive's answers at least
    as high were right that often at; without one, ``stream-rules`` refuses it (its score is no probability)."""
    from vpr_edge.calibration import fit, write
    from vpr_edge.errors import InputError

    rng = np.random.default_rng(4)
    s = rng.uniform(0, 2, 300)
    curve = fit(s, rng.random(300) < s / 2, 1, answered=s >= 1.0)
    write(tmp_path / "cal.json", {"stream-rules": curve}, "test")
    rules = {"mode": "stream-rules", "calibration": tmp_path / "cal.json"}
    for target in (0.7, 0.9):
        loc = Localizer(api_map, target_precision=target, **rules)
        assert loc.threshold == curve.line(target) and np.isfinite(loc.threshold)
    assert Localizer(api_map, **rules).threshold == 1.0   # stream-rules' own line
    with pytest.raises(InputError, match="cal.json, the labelled drive, does not show") as short:   # before the map
        Localizer(api_map.with_name("missing.npz"), target_precision=0.999, **rules)
    assert short.value.inputs == ("target_precision",)
    with pytest.raises(InputError, match="not the probability"):
        Localizer(api_map, mode="stream-rules", target_precision=0.9)
    assert Localizer(api_map, target_precision=0.9).threshold == 0.9   # stream's score is the probability


def test_constructed_and_pushed_from_threads(api_map: Path, small_queries: Path) -> None:
    images = [load_image(f) for f in sorted(small_queries.iterdir())[:6]]
    results: dict[int, list] = {}

    def drive(i: int) -> None:
        loc = Localizer(api_map, mode="single")
        results[i] = [loc.push(im).ref_index for im in images]

    threads = [threading.Thread(target=drive, args=(i,)) for i in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(results) == 3 and results[0] == results[1] == results[2]


def test_threads_limit_blas() -> None:
    pytest.importorskip("threadpoolctl")
    from threadpoolctl import threadpool_info

    from vpr_edge.threads import use_threads

    code = ("from vpr_edge.threads import use_threads; from threadpoolctl import threadpool_info;"
            "use_threads(1); print(sorted({p['num_threads'] for p in threadpool_info() if p['user_api'] == 'blas'}))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.stdout.strip() in ("[1]", "[]"), proc.stdout + proc.stderr
    assert use_threads(0) >= 1 and threadpool_info is not None


@pytest.mark.slow
def test_local_search_reads_only_the_window(api_map: Path, small_queries: Path) -> None:
    """With a local search (window 3 on the 111-place sample map) push computes only the similarities the
    matcher asks for, and answers as the matcher does on the full similarity matrix (evaluate's path)."""
    loc = Localizer(api_map, params={"window": 3, "hold": 0.5, "probe": 16}, threads=1, standardise=False)
    files = sorted(small_queries.iterdir())
    sizes: list[int] = []
    real = loc.map.scores
    loc.query.map = type(loc.map)(loc.map.stored, loc.map.names, loc.map.encoder, loc.map.meta)   # spied
    object.__setattr__(loc.map, "scores", lambda q, kind="cosine", rows=None: sizes.append(
        len(loc.names) if rows is None else len(rows)) or real(q, kind, rows))
    pushed = [loc.push(load_image(f)) for f in files]
    assert min(sizes) < len(loc.names)                 # some frames read a window (+ the probe sample)
    enc = loc.encode([load_image(f) for f in files])
    want = loc.matcher.run(loc.similarity(enc), still=loc.matcher.cue(enc))
    assert [m.ref_index if not m.lost else int(r) for m, r in zip(pushed, want.refs)] == list(want.refs)
    np.testing.assert_allclose([m.score for m in pushed], want.scores, atol=1e-5)


def test_push_gives_the_matcher_the_motion_cue(api_map: Path, small_queries: Path) -> None:
    """A stream with stops (frames repeated): push answers as the matcher does on the whole similarity matrix
    with each frame's likeness to the last frame that moved (``Matcher.cue``, what evaluate passes), not as it
    does without the cue; reset forgets the anchor."""
    files = sorted(small_queries.iterdir())
    order = [0, 1, 2, 3, 4, 5, 5, 5, 5, 5, 5, 5, 5, 6, 7, 8, 9, 9, 9, 9, 9, 9, 10, 11, 12, 13, 14]
    images = [load_image(files[i]) for i in order]
    loc = Localizer(api_map, threads=1, standardise=False)   # similarity() below: raw cosines
    pushed = [loc.push(im) for im in images]
    enc = loc.encode(images)
    cue = loc.matcher.cue(enc)
    np.testing.assert_allclose(cue, stillness(enc, loc.matcher.still_threshold), equal_nan=True)
    assert np.isnan(cue[0]) and np.allclose(cue[[6, 7, 12, 17]], 1.0) and (cue[[1, 13, 22]] < 0.5).all()
    want = loc.matcher.run(loc.similarity(enc), still=cue)
    blind = loc.matcher.run(loc.similarity(enc))
    assert [m.ref_index if not m.lost else int(r) for m, r in zip(pushed, want.refs)] == list(want.refs)
    np.testing.assert_allclose([m.score for m in pushed], want.scores, atol=1e-5)
    assert not np.allclose(want.scores, blind.scores, atol=1e-5)      # the cue changed something
    loc.reset()
    again = [loc.push(im) for im in images]
    np.testing.assert_allclose([m.score for m in again], want.scores, atol=1e-5)


def test_evaluate_runs_the_stream_matcher_as_localize_does(api_map: Path, small_queries: Path,
                                                            tmp_path: Path) -> None:
    """evaluate from a map computes the same motion cue as Localizer (each decoded frame's likeness to the one
    before), so its stream answers and scores on a stream with stops are those of push."""
    import shutil

    from vpr_edge.evaluation import Source, Truth, evaluate
    from vpr_edge.evaluation.truth import write_ground_truth

    files = sorted(small_queries.iterdir())
    order = [0, 1, 2, 3, 4, 5, 5, 5, 5, 5, 5, 5, 5, 6, 7, 8, 9, 9, 9, 9, 9, 9, 10, 11, 12, 13, 14]
    stream = tmp_path / "stops"
    stream.mkdir()
    for i, src in enumerate(order):
        shutil.copy(files[src], stream / f"{i:04d}{files[src].suffix}")
    write_ground_truth(tmp_path / "stops.csv", [[i] for i in order])
    report = evaluate(Source(map=api_map, queries=stream, threads=1), Truth(gt=tmp_path / "stops.csv"),
                      {"stream": get_matcher("stream")}, tolerance=1).reports["stream"]
    loc = Localizer(api_map, threads=1)
    pushed = [loc.push(load_image(f)) for f in sorted(stream.iterdir())]
    np.testing.assert_allclose([m.score for m in pushed], report.scores, atol=1e-5)
    assert [m.ref_index for m in pushed if not m.lost] == [int(r) for r, lost in zip(report.refs, report.lost)
                                                           if not lost]
    assert [m.lost_why for m in pushed] == list(report.why)          # the same reason for each lost frame
    assert all((m.lost_why is None) == (not m.lost) for m in pushed) and pushed[0].lost_why == "off-map"
    blind = evaluate(Source(map=api_map, queries=stream, threads=1), Truth(gt=tmp_path / "stops.csv"),
                     {"stream": get_matcher("stream").with_params(still=0.0)}, tolerance=1).reports["stream"]
    assert not np.allclose(blind.scores, report.scores, atol=1e-5)       # the cue made a difference here


def test_a_map_rewritten_in_place_stops_cleanly(tmp_path: Path, api_map: Path, small_queries: Path,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """``cp new.npz route.npz`` while a memory-mapped map is in use (the same file truncated and rewritten):
    the next frame stops with MapChanged naming the map, before any of its pages is read (reading a
    truncated mapping would kill the process with SIGBUS). A map below ``MMAP_MIN_BYTES`` is read into memory
    and a rewrite cannot touch it."""
    import shutil

    import vpr_edge.map.query as query
    from vpr_edge.errors import MapChanged

    route = tmp_path / "route.npz"
    shutil.copy(api_map, route)
    images = [load_image(f) for f in sorted(small_queries.iterdir())[:4]]
    small = Localizer(route, threads=1)
    assert not small.query.mapped
    monkeypatch.setattr(query, "MMAP_MIN_BYTES", 0)
    loc = Localizer(route, threads=1)
    assert loc.query.mapped
    loc.push(images[0])
    with open(route, "r+b") as f:   # what cp does to an existing file: truncate, write
        data = f.read()
        f.seek(0)
        f.truncate()
        f.write(data[: len(data) // 2])
    with pytest.raises(MapChanged, match=f"{route}: the map file changed while in use"):
        loc.push(images[1])
    assert small.push(images[1]).frame_index == 0           # the in-memory map goes on


def test_confidence_is_the_modes_own_probability(tmp_path: Path) -> None:
    """Without a calibration, a mode that models the probability that its answer is right gives it as the
    line's ``confidence``: stream's answers given are at least the target precision sure, their score
    that probability; a lost frame and a mode without a model give none."""
    from helpers import driven_encodings
    from vpr_edge.matchers.constants import TARGET_PRECISION

    refs, queries, truth = driven_encodings(400, 160, noise=1.0, seed=6)
    np.save(tmp_path / "refs.npy", refs)
    proc = subprocess.run([sys.executable, "-m", "vpr_edge", "build-map", str(tmp_path / "refs.npy"), "-o",
                           str(tmp_path / "m.npz")], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    prob = Localizer(tmp_path / "m.npz", mode="stream", threads=1)
    got = [prob.push_encoding(q) for q in queries]
    given = [m for m in got if not m.lost]
    assert len(given) > 30
    assert all(TARGET_PRECISION <= m.confidence <= 1.0 and m.score == m.confidence for m in given)
    assert all(m.confidence is None for m in got if m.lost)
    plain = Localizer(tmp_path / "m.npz", mode="stream-rules", threads=1)
    assert all(plain.push_encoding(q).confidence is None for q in queries[:20])
