"""Global descriptors as input (what NetVLAD, CosPlace, EigenPlaces, MixVPR and hloc users hold): .npy and
hloc-style .h5 files through build-map, localize, evaluate and Localizer, and every bad file refused in one
line before any work."""
from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from helpers import run
from vpr_edge import Localizer
from vpr_edge.evaluation.truth import write_ground_truth
from vpr_edge.map import load_map


def descriptor_drives(rng: np.random.Generator, n: int = 60, dims: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """A route of ``n`` places (each place's descriptor its own, neighbours a little alike, as a network's
    are along a road) and a second drive of it: each place's descriptor plus noise."""
    own = rng.normal(size=(n + 1, dims))
    refs = own[1:] + 0.5 * own[:-1]
    queries = refs + 0.8 * rng.normal(size=(n, dims))
    return refs.astype(np.float32), queries.astype(np.float32)


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> Path:
    w = tmp_path_factory.mktemp("desc")
    refs, queries = descriptor_drives(np.random.default_rng(0))
    np.save(w / "refs.npy", refs.astype(np.float16))
    np.save(w / "queries.npy", queries)
    write_ground_truth(w / "gt.csv", [[i] for i in range(len(queries))])
    return w


def test_npy_round_trip_build_localize_evaluate(files: Path, tmp_path: Path) -> None:
    """build-map REFS.npy makes a map of 'descriptors of D dims' (about D bytes a place as int8); localize and
    evaluate take a .npy stream; Localizer answers as localize does; the route is followed."""
    m = tmp_path / "m.npz"
    built = run("build-map", files / "refs.npy", "-o", m)
    assert built.returncode == 0, built.stderr
    pm = load_map(m)
    assert pm.features == {"name": "descriptors", "params": {"dims": 32}} and pm.stored.bytes_per_place == 36
    assert pm.names[:2] == ["000000", "000001"]
    loc = run("localize", "-m", m, "-s", files / "queries.npy", "-o", tmp_path / "out.csv")
    assert loc.returncode == 0, loc.stderr
    rows = list(csv.DictReader((tmp_path / "out.csv").open()))
    answered = [(int(r["frame_index"]), int(r["ref_index"])) for r in rows if r["lost"] == "0"]
    assert len(rows) == 60 and len(answered) > 40 and np.mean([abs(a - b) <= 2 for a, b in answered]) > 0.9
    ev = run("evaluate", "-m", m, "-q", files / "queries.npy", "--gt", files / "gt.csv", "--modes", "stream",
             "--tolerance", "2", "--json", tmp_path / "e.json")
    assert ev.returncode == 0, ev.stderr
    assert json.loads((tmp_path / "e.json").read_text())["modes"]["stream"]["recall_at_1"] > 0.9
    api = Localizer(m, threads=1)
    queries = np.load(files / "queries.npy")
    pushed = [api.push_encoding(api.query.encode_descriptors(q[None])[0], f"{i:06d}") for i, q in enumerate(queries)]
    assert [str(p.ref_index if not p.lost else "") for p in pushed] == [r["ref_index"] for r in rows]


def test_h5_in_hlocs_layout(files: Path, tmp_path: Path) -> None:
    """hloc's global-feats file (a group per image, dataset global_descriptor; nested names kept): the same
    map as the .npy of the same vectors in name order, and frames named after their groups."""
    h5py = pytest.importorskip("h5py")
    refs, queries = np.load(files / "refs.npy"), np.load(files / "queries.npy")
    for name, data in (("refs.h5", refs), ("queries.h5", queries)):
        with h5py.File(tmp_path / name, "w") as f:
            for i, v in enumerate(data):
                f.create_group(f"db/img{i:04d}.jpg").create_dataset("global_descriptor", data=v)
    a, b = tmp_path / "a.npz", tmp_path / "b.npz"
    assert run("build-map", tmp_path / "refs.h5", "-o", a).returncode == 0
    assert run("build-map", files / "refs.npy", "-o", b).returncode == 0
    np.testing.assert_array_equal(load_map(a).stored.values, load_map(b).stored.values)
    assert load_map(a).names[0] == "db/img0000.jpg"
    out = run("localize", "-m", a, "-s", tmp_path / "queries.h5")
    assert out.returncode == 0 and "db/img0005.jpg" in out.stdout


@pytest.mark.parametrize("make, needle", [
    (lambda w: np.save(w / "bad.npy", np.zeros((5, 31), np.float32) + 1), "descriptors of 31 dims, but the map's"),
    (lambda w: np.save(w / "bad.npy", np.ones((5, 32), np.int32)), "2-D float array"),
    (lambda w: np.save(w / "bad.npy", np.ones(32, np.float32)), "2-D float array"),
    (lambda w: np.save(w / "bad.npy", np.where(np.arange(5)[:, None] == 3, np.nan, np.ones((5, 32)))),
     "row 3 holds NaN or infinite values"),
    (lambda w: np.save(w / "bad.npy", np.array([{"x": 1}] * 5, dtype=object), allow_pickle=True),
     "holds Python objects, which vpr-edge never unpickles"),
    (lambda w: (w / "bad.npy").write_bytes(b"\x93NUMPY garbage"), "not a readable .npy array"),
])
def test_bad_descriptor_streams_are_one_line(files: Path, tmp_path: Path, make, needle: str) -> None:
    m = tmp_path / "m.npz"
    assert run("build-map", files / "refs.npy", "-o", m).returncode == 0
    make(tmp_path)
    out = tmp_path / "out.csv"
    proc = run("localize", "-m", m, "-s", tmp_path / "bad.npy", "-o", out)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and "bad.npy" in lines[0] and needle in lines[0], proc.stderr
    assert not out.exists()


def test_bad_descriptor_references_and_mixed_inputs(files: Path, tmp_path: Path, small_queries: Path) -> None:
    """A bad reference file, image options with descriptors, an .h5 without global descriptors, images for a
    map of descriptors and descriptors for a map of images: one line each, nothing written."""
    h5py = pytest.importorskip("h5py")
    with h5py.File(tmp_path / "local.h5", "w") as f:
        f.create_group("img.jpg").create_dataset("keypoints", data=np.zeros((3, 2)))
    np.save(tmp_path / "nan.npy", np.full((4, 8), np.inf, np.float32))
    m = tmp_path / "m.npz"
    cases = [(("build-map", tmp_path / "local.h5", "-o", m), "no global_descriptor datasets"),
             (("build-map", tmp_path / "nan.npy", "-o", m), "row 0 holds NaN or infinite values"),
             (("build-map", files / "refs.npy", "-o", m, "--components", "8"), "drop --components"),
             (("build-map", files / "refs.npy", "-o", m, "--encoding", "ifv"), "drop --encoding ifv"),
             (("build-map", tmp_path / "none.npy", "-o", m), "none.npy: no such descriptor file")]
    for args, needle in cases:
        proc = run(*args)
        assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and needle in proc.stderr, (args, proc.stderr)
        assert not m.exists()
    assert run("build-map", files / "refs.npy", "-o", m).returncode == 0
    images = run("localize", "-m", m, "-s", small_queries)
    assert images.returncode == 2 and "holds global descriptors of 32 dims" in images.stderr
    img_map = tmp_path / "img.npz"
    assert run("build-map", small_queries, "-o", img_map, "--components", "2").returncode == 0
    desc = run("evaluate", "-m", img_map, "-q", files / "queries.npy", "--gt", files / "gt.csv")
    assert desc.returncode == 2 and "global descriptors given" in desc.stderr and desc.stderr.count("\n") == 1
