"""Maps of several drives: the route graph against plain loops, the streaming matcher across drives (against a
naive recursion, and on planted routes), and build-map / localize / evaluate / info with drives."""
from __future__ import annotations

import csv
import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from helpers import invoke, naive_road_over_drives, planted_drives
from vpr_edge.map import load_map
from vpr_edge.map.drives import Drives
from vpr_edge.matchers import MATCHERS
from vpr_edge.matchers.road import RoadMatcher
from vpr_edge.matchers.stream_config import StreamConfig
from vpr_edge.matchers.route import RouteGraph, max_outside, merge, minus, places
from vpr_edge.positions import Positions


# --- the route graph ----------------------------------------------------------------------------------------


def naive_near(graph: RouteGraph, ref: int, w: int) -> set[int]:
    """Places within ``w`` steps of ``ref``: along its sequence either way, and one junction hop."""
    def seq(r: int) -> tuple[int, int]:
        return graph.bounds(r)

    first, last = seq(ref)
    out = {p for p in range(first, last + 1) if abs(p - ref) <= w}
    for sources, targets in graph.junctions:
        ahead = [s for s in sources if first <= s <= last and 0 <= s - ref <= w]
        if ahead:
            left = w - (min(ahead) - ref) - 1
            for t in targets:
                out |= {p for p in range(t, seq(t)[1] + 1) if p - t <= left}
        behind = [t for t in targets if first <= t <= last and 0 <= ref - t <= w]
        if behind:
            left = w - (ref - max(behind)) - 1
            for s in sources:
                out |= {p for p in range(seq(s)[0], s + 1) if s - p <= left}
    return out


def test_near_against_a_plain_walk() -> None:
    rng = np.random.default_rng(0)
    for _ in range(40):
        counts = rng.integers(3, 15, rng.integers(1, 5))
        d = Drives.of([f"d{i}" for i in range(len(counts))], counts)
        pool = d.junctions()
        extra = [(np.array([int(rng.integers(0, d.n_refs))]), np.array([int(rng.integers(0, d.n_refs))]))]
        graph = RouteGraph(d.n_refs, d.starts, tuple(pool + extra))
        for ref in range(d.n_refs):
            for w in (0, 1, 3, 7):
                got = set(places(graph.near(ref, w)).tolist())
                assert got == naive_near(graph, ref, w), (counts, ref, w)


def test_interval_helpers() -> None:
    assert merge([(5, 8), (0, 3), (2, 4), (9, 9)]) == [(0, 4), (5, 8)]
    assert merge([(0, 3), (5, 8)], gap=3) == [(0, 8)]
    assert minus([(0, 10)], [(2, 4), (6, 12)]) == [(0, 2), (4, 6)]
    assert minus([(0, 3), (5, 9)], [(0, 3)]) == [(5, 9)]
    values = np.array([5.0, 1.0, 7.0, 2.0, 9.0])
    assert max_outside(values, None, [(2, 5)]) == 5.0
    assert max_outside(values[[0, 2, 4]], np.array([0, 2, 4]), [(0, 1), (4, 5)]) == 7.0
    assert max_outside(values, None, [(0, 5)]) == 0.0


def test_a_single_drive_is_a_line() -> None:
    d = Drives.single("run", 10)
    assert d.junctions() == [] and RouteGraph(10, d.starts, tuple(d.junctions())).simple
    with pytest.raises(ValueError):
        RouteGraph(10, np.array([1, 5]))


# --- the matcher across drives, against a naive recursion ------------------------------------------------------


@pytest.mark.parametrize("grid,vmax", [(1, 2.0), (2, 1.5)])
def test_matcher_across_drives_against_naive_recursion(grid: int, vmax: float) -> None:
    rng = np.random.default_rng(1)
    d = Drives.of(["a", "b", "c"], [7, 5, 8])
    junctions = d.junctions() + [(np.array([3]), np.array([15]))]   # a's middle may continue into c's middle
    graph = RouteGraph(d.n_refs, d.starts, tuple(junctions))
    sim = rng.normal(size=(9, d.n_refs))
    params = dict(grid=grid, vmax=vmax, decay=0.9, bias=0.3, turn=0.5, stop_gain=0.3, stop_decay=0.95)
    config = StreamConfig.of(dict(memory=1e12, lock=1.0, rival_window=1, window=0, probe=1000, check=10, span=1,
                                  hold=2.0, seek=8, peaks=8, seek_frames=4, still=0.0, still_memory=30, evidence=-99.0,
                                  evidence_decay=0.5, hub=-99.0, unique=0.0, confirm=1, stuck=0, trust=1.0, **params))
    m = RoadMatcher(d.n_refs, config, graph=graph)
    for row in sim:
        m.update(row)
    np.testing.assert_allclose(m.h, naive_road_over_drives(sim, graph, **params), atol=1e-4)


# --- planted routes ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("speed", [1.0, 2.0])
@pytest.mark.parametrize("window", [0, 20])
def test_a_vehicle_follows_the_route_across_shuffled_drives(speed: float, window: int) -> None:
    """The drives given in shuffled order cost little more than a one-folder map of the same places: without
    positions a drive's end may continue into any drive's start, so the filter spends a few frames finding
    which (no more than 4 frames more wrong or lost in the 15 after each join); without the drives (the map
    read as one route, the false joins) they cost more."""
    order = [2, 0, 3, 1]
    sim, truth, drives = planted_drives(order, [150, 150, 150, 150], noise=0.5, seed=3, speed=speed)
    stream = MATCHERS["stream"].with_params(window=window)
    graph = RouteGraph(drives.n_refs, drives.starts, tuple(drives.junctions()))
    route = np.concatenate([np.arange(drives.items[k].first, drives.items[k].last + 1) for k in order])
    one = stream.run(sim[:, route], k=1)           # one folder, the places in route order
    joined = replace(stream, graph=graph).run(sim, k=1)
    plain = stream.run(sim, k=1)                   # the drives' map read as one route: the false joins

    def bad(res, places) -> np.ndarray:
        return (np.abs(places[res.refs] - truth) > 2) | (res.scores < stream.min_confidence)

    at = np.arange(drives.n_refs)
    one_bad, joined_bad, plain_bad = bad(one, route), bad(joined, at), bad(plain, at)
    joins = np.flatnonzero(np.diff([drives.index(t) for t in truth]) != 0) + 1
    assert joined_bad[15:].sum() <= one_bad[15:].sum() + 4 * len(joins)   # the joins' cost, nothing else
    for j in joins:
        assert joined_bad[j:j + 15].sum() <= one_bad[j:j + 15].sum() + 4, j
    assert plain_bad[15:].sum() > joined_bad[15:].sum() + 5


def test_two_experiences_of_one_road_and_a_detour() -> None:
    """Drive 1 repeats drive 0's road; the vehicle drives it, leaves the map, comes back: either experience
    is an answer, as right as with one experience, and the off-map frames are lost."""
    sim, truth, drives = planted_drives([0], [200, 200], noise=0.3, seed=4)
    sim[:, 200:] = sim[:, :200] + np.random.default_rng(5).normal(0, 0.2, (len(sim), 200))
    sim[80:110] = np.random.default_rng(6).normal(0.0, 0.3, (30, 400))   # off the map
    graph = RouteGraph(drives.n_refs, drives.starts, tuple(drives.junctions()))
    two = replace(MATCHERS["stream"], graph=graph).run(sim, k=1)
    one = MATCHERS["stream"].run(sim[:, :200], k=1)
    right, lost = [], []
    for res in (two, one):
        place = np.where(res.refs >= 200, res.refs - 200, res.refs)
        line = MATCHERS["stream"].min_confidence
        right.append((np.abs(place - truth) <= 2) & (res.scores >= line))
        lost.append((res.scores[80:110] < line).mean())
    for part in (slice(20, 80), slice(125, 200)):
        assert right[0][part].mean() >= right[1][part].mean() - 0.05, part
    assert lost[0] >= lost[1] - 0.1 and lost[0] > 0.75


# --- junctions from positions -----------------------------------------------------------------------------------


def test_drives_meet_where_their_positions_do() -> None:
    # drive a runs x = 0..9 m, drive b runs x = 10..19 m (a's end meets b's start), c runs elsewhere (y = 500)
    xs = np.r_[np.arange(10.0), np.arange(10.0, 20.0), np.arange(10.0)]
    ys = np.r_[np.zeros(20), np.full(10, 500.0)]
    heading = np.full(30, 90.0)
    pos = Positions(np.c_[xs, ys], "local", heading, np.full(30, np.nan))
    d = Drives.of(["a", "b", "c"], [10, 10, 10])
    joins = {(int(s[0]), int(t[0])) for s, t in d.junctions(pos)}
    assert joins == {(9, 11), (8, 10)}   # a's end -> the place after b's nearest; b's start <- the one before a's
    pos_back = Positions(np.c_[xs, ys], "local", np.r_[np.full(10, 90.0), np.full(20, 270.0)], np.full(30, np.nan))
    assert d.junctions(pos_back) == []   # pointing the other way: no junction


# --- the command line --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def drives_dir(tmp_path_factory: pytest.TempPathFactory, small_refs: Path) -> Path:
    """The 24 sample references cut into three drives of 8 whose frames share names (frame_0000.jpg ...)."""
    root = tmp_path_factory.mktemp("drives")
    files = sorted(small_refs.glob("*.jpg"))
    for k in range(3):
        (root / f"d{k}").mkdir()
        for i, f in enumerate(files[8 * k:8 * k + 8]):
            shutil.copy(f, root / f"d{k}" / f"frame_{i:04d}.jpg")
    return root


def test_build_map_of_drives_localize_evaluate_info(tmp_path: Path, drives_dir: Path, small_queries: Path) -> None:
    out = tmp_path / "m.npz"
    code, _, err = invoke("build-map", drives_dir / "d2", drives_dir / "d0", drives_dir / "d1", "-o", out,
                          "--components", "4")
    assert code == 0, err
    assert "24 references in 3 drives" in err
    pm = load_map(out)
    assert pm.drives.names == ["d2", "d0", "d1"] and [d.count for d in pm.drives.items] == [8, 8, 8]
    assert pm.names[:2] == ["frame_0000.jpg", "frame_0001.jpg"] and pm.names[8] == "frame_0000.jpg"
    info = json.loads(invoke("info", out)[1])
    assert [d["name"] for d in info["drives"]] == ["d2", "d0", "d1"]
    code, stdout, err = invoke("localize", "-m", out, "-s", small_queries, "--format", "jsonl")
    assert code == 0, err
    lines = [json.loads(x) for x in stdout.splitlines()]
    answered = [x for x in lines if not x["lost"]]
    assert all(x["drive"] == pm.drives.of_ref(x["ref_index"]).name for x in answered)
    assert all(x["drive"] is None for x in lines if x["lost"])
    # ground truth naming references DRIVE/NAME: query i shows reference i of the original folder
    gt = tmp_path / "gt.csv"
    with open(gt, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["query", "references"])
        for i in range(24):
            w.writerow([i, f"d{i // 8}/frame_{i % 8:04d}.jpg"])
    code, _, err = invoke("evaluate", "-m", out, "-q", small_queries, "--gt", gt, "--modes", "single",
                          "--json", tmp_path / "r.json")
    assert code == 0, err
    bad = tmp_path / "bad.csv"
    bad.write_text("query,references\n0,d9/frame_0000.jpg\n")
    code, _, err = invoke("evaluate", "-m", out, "-q", small_queries, "--gt", bad, "--modes", "single")
    assert code == 2 and err.count("\n") == 1 and "bad.csv" in err and "d9/frame_0000.jpg" in err


def test_append_adds_drives_and_keeps_the_old_places(tmp_path: Path, drives_dir: Path) -> None:
    out = tmp_path / "m.npz"
    assert invoke("build-map", f"first={drives_dir / 'd0'}", "-o", out, "--components", "4")[0] == 0
    before = load_map(out)
    code, _, err = invoke("build-map", drives_dir / "d1", drives_dir / "d2", "-o", out, "--append")
    assert code == 0, err
    after = load_map(out)
    assert after.drives.names == ["first", "d1", "d2"]
    for key in ("values", "scale"):
        a, b = before.stored.to_arrays(), after.stored.to_arrays()
        if key in a:
            assert np.array_equal(np.asarray(b[key])[:8], np.asarray(a[key])), key
    # the same drive name again: refused, the map untouched
    digest = out.read_bytes()
    code, _, err = invoke("build-map", drives_dir / "d1", "-o", out, "--append")
    assert code == 2 and err.count("\n") == 1 and "'d1'" in err and out.read_bytes() == digest


def test_bad_drives_are_one_line(tmp_path: Path, drives_dir: Path) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    out = tmp_path / "m.npz"
    vectors = tmp_path / "v.npy"
    np.save(vectors, np.random.default_rng(0).normal(size=(5, 16)).astype(np.float32))
    pos = tmp_path / "p.csv"
    pos.write_text("x,y\n" + "".join(f"{i},0\n" for i in range(8)))
    checks = [
        (("build-map", drives_dir / "d0", drives_dir / "d0", "-o", out), ("two drives named 'd0'",)),
        (("build-map", drives_dir / "d0", empty, "-o", out), ("empty",)),
        (("build-map", drives_dir / "d0", vectors, "-o", out), ("v.npy", "not both")),
        (("build-map", drives_dir / "d0", drives_dir / "d1", "-o", out, "--positions", pos), ("one per drive",)),
        (("build-map", drives_dir / "d0", drives_dir / "d1", "-o", out, "--positions", pos, "--positions", pos,
          "--positions", pos), ("3 time(s) for 2 drives",)),
    ]
    for args, needles in checks:
        code, _, err = invoke(*args)
        assert code == 2 and err.count("\n") == 1 and all(n in err for n in needles), (args, err)
    assert not out.exists()


def test_descriptor_drives(tmp_path: Path) -> None:
    rng = np.random.default_rng(2)
    a, b = tmp_path / "north.npy", tmp_path / "south.npy"
    va, vb = rng.normal(size=(30, 16)).astype(np.float32), rng.normal(size=(20, 16)).astype(np.float32)
    np.save(a, va), np.save(b, vb)
    out = tmp_path / "m.npz"
    code, _, err = invoke("build-map", b, a, "-o", out)
    assert code == 0, err
    pm = load_map(out)
    assert pm.drives.names == ["south", "north"] and len(pm.names) == 50
    direct = np.vstack([vb, va])
    np.testing.assert_allclose(pm.encodings, direct / np.linalg.norm(direct, axis=1, keepdims=True), atol=0.02)
    code, stdout, err = invoke("localize", "-m", out, "-s", a, "--format", "jsonl")
    assert code == 0, err
    lines = [json.loads(x) for x in stdout.splitlines()]
    assert sum(x["drive"] == "north" and x["ref_index"] - 20 == x["frame_index"] for x in lines) >= 20
