"""Front ends against plain-loop references and OpenCV called directly; every front end x encoding x matcher
through build-map / localize / evaluate; maps refuse queries described or encoded another way."""
from __future__ import annotations

import csv
import io
import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from helpers import invoke
from vpr_edge.cli import app
from vpr_edge.encoders import ENCODERS
from vpr_edge.features import FRONT_ENDS, grey
from vpr_edge.features.hog import Hog
from vpr_edge.features.ldb import Ldb, all_bits, select_bits
from vpr_edge.features.patches import Patches
from vpr_edge.features.sift import DenseSift, KeypointSift
from vpr_edge.frames.images import load_image
from vpr_edge.map import PlaceMap, load_map, map_front_end, save_map
from vpr_edge.matchers import MATCHERS
from vpr_edge.features.patches import pixel_descriptor
from vpr_edge.evaluation.truth import write_ground_truth


@pytest.fixture(scope="module")
def images(small_refs: Path) -> list[np.ndarray]:
    return [load_image(f) for f in sorted(small_refs.iterdir())[:4]]


# ----------------------------------------------------------------------------------------------------- LDB
def naive_ldb(img: np.ndarray, levels: tuple[int, ...]) -> list[bool]:
    """LDB of one (S, S) image with plain loops over cells, pixels and pairs."""
    s = img.shape[0]
    bits: list[bool] = []
    for level in levels:
        edges = [int(round(v)) for v in np.linspace(0, s, level + 1)]
        values = []
        for r in range(level):
            for c in range(level):
                y0, y1, x0, x1 = edges[r], edges[r + 1], edges[c], edges[c + 1]
                ym, xm = (y0 + y1) // 2, (x0 + x1) // 2

                def mean(ya: int, yb: int, xa: int, xb: int) -> float:
                    vals = [img[y, x] for y in range(ya, yb) for x in range(xa, xb)]
                    return sum(vals) / max(len(vals), 1)
                values.append((mean(y0, y1, x0, x1), mean(y0, y1, xm, x1) - mean(y0, y1, x0, xm),
                               mean(ym, y1, x0, x1) - mean(y0, ym, x0, x1)))
        for i in range(len(values)):
            for j in range(i + 1, len(values)):
                bits += [values[i][f] > values[j][f] for f in range(3)]
    return bits


def test_ldb_matches_plain_loops() -> None:
    rng = np.random.default_rng(0)
    img = rng.integers(0, 255, size=(3, 20, 20)).astype(np.float64)
    img[2] = 7.0                                               # flat image: every comparison false
    got = all_bits(img, (2, 3, 5))
    assert got.shape == (3, 3 * (6 + 36 + 300))
    for b in range(3):
        assert got[b].tolist() == naive_ldb(img[b], (2, 3, 5))
    assert not got[2].any()


def test_ldb_hamming_is_cosine(images: list[np.ndarray]) -> None:
    ldb = Ldb(bits=tuple(range(0, 1386, 5)))
    x, mask = ldb.local(images)
    assert mask is None and x.shape == (4, 1, 278) and set(np.unique(x)) <= {-1.0, 1.0}
    a, b = x[:, 0] > 0, x[:, 0]
    hamming = (a[:, None, :] != a[None, :, :]).sum(axis=2)
    cos = (b @ b.T) / 278
    np.testing.assert_allclose(cos, 1 - 2 * hamming / 278, atol=1e-6)


def test_bit_selection() -> None:
    rng = np.random.default_rng(1)
    base = rng.random((200, 1)) < 0.5
    bits = np.concatenate([base, base, ~base, rng.random((200, 3)) < 0.5, np.ones((200, 2), bool),
                           rng.random((200, 1)) < 0.05], axis=1)
    chosen = select_bits(bits, 4, "entropy")
    assert len(set(chosen.tolist()) & {0, 1, 2}) == 1          # three copies of one bit: one kept
    assert not set(chosen.tolist()) & {6, 7, 8}                # constant and nearly constant bits left out
    assert select_bits(bits, 4, "random", seed=3).tolist() == select_bits(bits, 4, "random", seed=3).tolist()
    assert len(select_bits(bits, 20)) == 9


# ---------------------------------------------------------------------------------------- HOG, SIFT, pixels
def test_hog_blocks_are_opencv_whole_image_descriptor(images: list[np.ndarray]) -> None:
    hog = Hog()
    x, _ = hog.local(images)
    assert x.shape == (4, 105, 36) == (4, hog.n_local, hog.dim)
    ref = cv2.HOGDescriptor((128, 64), (16, 16), (8, 8), (8, 8), 9).compute(grey(images[1], (128, 64)))
    np.testing.assert_array_equal(x[1].reshape(-1), ref)       # encoding none = the whole image's HOG


def test_dense_sift_is_opencv_on_the_grid(images: list[np.ndarray]) -> None:
    sift = DenseSift()
    x, mask = sift.local(images)
    assert mask is None and x.shape == (4, 48, 128) and sift.n_local == 48
    kp = [cv2.KeyPoint(40.0, 24.0, 16.0)]                      # grid point (2, 1): row 1, column 2
    _, ref = cv2.SIFT_create().compute(grey(images[0], (128, 96)), kp)
    np.testing.assert_allclose(x[0, 1 * 8 + 2], ref[0])


def test_keypoint_sift_pads_and_masks(images: list[np.ndarray]) -> None:
    sift = KeypointSift(max_keypoints=16)
    blank = np.full((120, 160, 3), 128, np.uint8)
    x, mask = sift.local(images[:2] + [blank])
    assert x.shape == (3, 16, 128) and mask.shape == (3, 16)
    assert mask[0].sum() > 0 and not mask[2].any() and not x[2].any()
    assert np.all(np.linalg.norm(x[~mask], axis=1) == 0)        # padding is zeros


def test_pixel_patches_are_seqslam_image(images: list[np.ndarray]) -> None:
    x, _ = Patches().local(images)
    assert x.shape == (4, 32, 64)
    flat = pixel_descriptor(images[2]).reshape(4, 8, 8, 8).transpose(0, 2, 1, 3).reshape(32, 64)
    np.testing.assert_array_equal(x[2], flat)


# ------------------------------------------------------------------------------- the grid through the CLI
@pytest.fixture(scope="module")
def gt(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("gt") / "gt.csv"
    write_ground_truth(path, [[max(i - 2, 0) + j for j in range(5) if max(i - 2, 0) + j < 24] for i in range(24)])
    return path


@pytest.mark.slow
@pytest.mark.parametrize("front", list(FRONT_ENDS))
def test_every_front_end_encoding_and_matcher_runs(tmp_path: Path, small_refs: Path, small_queries: Path,
                                                     gt: Path, front: str) -> None:
    for encoding in ENCODERS:
        out = tmp_path / f"{front}-{encoding}.npz"
        code, _, err = invoke("build-map", small_refs, "-o", out, "--features", front, "--encoding", encoding,
                              "--components", "4", "--svm")
        if front == "sift-kp" and encoding == "none":          # keypoints have no fixed grid to flatten
            assert code == 2 and "fixed grid" in err and err.count("\n") == 1 and not out.exists()
            continue
        assert code == 0, err
        pm = load_map(out)
        assert pm.features["name"] == front and pm.encoder.name == encoding and pm.svm is not None
        code, stdout, err = invoke("evaluate", "-m", out, "-q", small_queries, "--gt", gt, "--modes", "all",
                                   "--json", tmp_path / "r.json")
        assert code == 0, err
        figures = json.loads((tmp_path / "r.json").read_text())["modes"]
        assert set(figures) == set(MATCHERS)                   # svm included: the map has one
        assert all(0.0 <= f["auc"] <= 1.0 for f in figures.values())
    code, stdout, err = invoke("localize", "-m", out, "-s", small_queries, "--mode", "svm")
    assert code == 0, err
    rows = list(csv.DictReader(stdout.splitlines()))
    assert len(rows) == 24 and all(0 <= int(r["ref_index"]) < 24 for r in rows)


def test_ldb_bits_recorded_and_reused(tmp_path: Path, small_refs: Path, images: list[np.ndarray]) -> None:
    out = tmp_path / "ldb.npz"
    assert invoke("build-map", small_refs, "-o", out, "--features", "ldb", "--encoding", "none")[0] == 0
    pm = load_map(out)
    front = map_front_end(pm, out)
    assert len(front.bits) == 256 and pm.stored.shape[1] == 256
    refs = pm.encode(*front.local(images[:2]))
    np.testing.assert_allclose(refs, pm.encodings[:2], atol=1e-6)   # queries described as the references were


def test_svm_round_trips_and_scores_by_one_product(tmp_path: Path, small_refs: Path) -> None:
    out = tmp_path / "svm.npz"
    assert invoke("build-map", small_refs, "-o", out, "--features", "hog", "--encoding", "vlad", "--components",
                  "4", "--svm", "--storage", "float32")[0] == 0
    pm = load_map(out)
    q = pm.encodings[:5]
    w, b = pm.svm.weights.dense(), pm.svm.bias
    naive = np.array([[float(np.dot(w[r], q[i]) + b[r]) for r in range(24)] for i in range(5)])
    np.testing.assert_allclose(pm.scores(q, "svm"), naive, rtol=1e-5, atol=1e-5)
    own = pm.scores(pm.encodings, "svm").argmax(axis=1)      # it fits its own data (positives: place +-1)
    assert np.mean(np.abs(own - np.arange(24)) <= 1) > 0.9
    assert pm.svm.meta["tolerance"] == 1
    small = tmp_path / "svm8.npz"
    save_map(pm, small, "int8")
    np.testing.assert_allclose(load_map(small, mmap=True).scores(q, "svm"), naive, atol=0.05)


def test_maps_refuse_queries_described_another_way(tmp_path: Path, small_refs: Path, small_queries: Path,
                                                   model_path: Path) -> None:
    hog, sift = tmp_path / "hog.npz", tmp_path / "sift.npz"
    cb = tmp_path / "sift_cb.npz"
    assert invoke("build-map", small_refs, "-o", hog, "--features", "hog", "--encoding", "none")[0] == 0
    assert invoke("build-map", small_refs, "-o", sift, "--features", "sift", "--encoding", "vlad", "--components",
                  "4", "--save-codebook", cb)[0] == 0
    checks = [
        (("localize", "-m", hog, "-s", small_queries, "--model", model_path), ("hog.npz", "takes no model")),
        (("build-map", small_refs, "-o", tmp_path / "x.npz", "--features", "hog", "--codebook", cb),
         ("sift_cb.npz", "fitted on sift descriptors", "hog")),
        (("build-map", small_refs, "-o", tmp_path / "x.npz", "--codebook", cb, "--encoding", "ifv"),
         ("sift_cb.npz", "encoding vlad")),
        (("build-map", small_refs, "-o", hog, "--append", "--features", "sift"), ("hog.npz", "--features")),
        (("localize", "-m", hog, "-s", small_queries, "--mode", "svm"), ("hog.npz", "build-map --svm")),
        (("evaluate", "-m", sift, "-q", small_queries, "--gt", tmp_path / "nogt.csv", "--modes", "svm"), ("nogt.csv",)),
    ]
    for args, needles in checks:
        code, _, err = invoke(*args)
        assert code == 2 and err.count("\n") == 1 and all(n in err for n in needles), (args, err)
    assert not (tmp_path / "x.npz").exists()
    # the API refuses encodings of another size with one line too
    pm = load_map(hog)
    with pytest.raises(Exception, match="hog \\+ none encodings have 3780"):
        pm.similarity(np.zeros((1, 100), np.float32))
    # a codebook from the same front end is reused: sift + vlad with it gives the same map
    again = tmp_path / "again.npz"
    assert invoke("build-map", small_refs, "-o", again, "--features", "sift", "--codebook", cb)[0] == 0
    np.testing.assert_allclose(load_map(again).encodings, load_map(sift).encodings, atol=1e-2)


@pytest.mark.slow
@pytest.mark.parametrize("recipe", [("ldb", "none", "--svm"), ("sift-kp", "vlad", "--no-tfidf")])
def test_runtime_imports_no_heavy_module_for_any_map(tmp_path: Path, small_refs: Path, small_queries: Path,
                                                     recipe: tuple[str, str, str]) -> None:
    front, encoding, extra = recipe
    out = tmp_path / "m.npz"
    args = ["build-map", small_refs, "-o", out, "--features", front, "--encoding", encoding, "--components", "4"]
    assert invoke(*args, *([extra] if extra == "--svm" else []))[0] == 0
    mode = "svm" if extra == "--svm" else "stream"
    code = ("import sys, runpy; sys.argv = ['vpr-edge', 'localize', '-m', sys.argv[1], '-s', sys.argv[2], "
            f"'--mode', '{mode}'];\n"
            "try: runpy.run_module('vpr_edge', run_name='__main__')\nexcept SystemExit: pass\n"
            "heavy = sorted(m for m in ('torch', 'sklearn', 'onnx', 'scipy') if m in sys.modules)\n"
            "print('HEAVY', heavy, file=sys.stderr)")
    proc = subprocess.run([sys.executable, "-c", code, str(out), str(small_queries)], capture_output=True,
                          text=True, timeout=300)
    assert "HEAVY []" in proc.stderr and len(proc.stdout.splitlines()) == 25, proc.stderr[-500:]


@pytest.mark.slow
def test_bundled_small_model(tmp_path: Path, small_refs: Path) -> None:
    """The bundled tap at 160x120: a quarter of the pixels, a 10x8 grid of the same 112 channels, and a map
    built with it localises with it."""
    import subprocess
    import sys

    from vpr_edge.features.cnn import FeatureExtractor
    from vpr_edge.resources import LARGE_MODEL_FILE, SMALL_MODEL_FILE, bundled_model

    SMALL_MODEL, BUNDLED_MODEL = bundled_model(SMALL_MODEL_FILE), bundled_model(LARGE_MODEL_FILE)

    small, big = FeatureExtractor(SMALL_MODEL, threads=1), FeatureExtractor(BUNDLED_MODEL, threads=1)
    assert small.size == (160, 120) and big.size == (320, 240)
    assert small.dim == big.dim == 112 and (small.n_local, big.n_local) == (10 * 8, 20 * 15)
    out = tmp_path / "small.map.npz"
    cli = [sys.executable, "-m", "vpr_edge"]
    proc = subprocess.run(cli + ["build-map", str(small_refs), "-o", str(out), "--model", str(SMALL_MODEL),
                                 "--components", "4"], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    proc = subprocess.run(cli + ["localize", "-m", str(out), "-s", str(small_refs), "--mode", "single"],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    refs = [int(row["ref_index"]) for row in csv.DictReader(io.StringIO(proc.stdout))]
    assert sum(r == i for i, r in enumerate(refs)) >= 0.9 * len(refs)     # each reference finds itself


def naive_fit(img: np.ndarray, size: tuple[int, int], policy: str, fill: tuple[int, int, int]) -> np.ndarray:
    """The resize policies spelled out: scale factors per policy, then a canvas filled / cut pixel by pixel."""
    w, h = size
    ih, iw = img.shape[:2]
    if policy == "stretch":
        return cv2.resize(img, size, interpolation=cv2.INTER_AREA if iw > w else cv2.INTER_LINEAR)
    f = (min if policy == "pad" else max)(w / iw, h / ih)
    tw, th = max(1, round(iw * f)), max(1, round(ih * f))
    scaled = cv2.resize(img, (tw, th), interpolation=cv2.INTER_AREA if iw > tw else cv2.INTER_LINEAR)
    out = np.zeros((h, w, 3), np.uint8)
    for y in range(h):
        for x in range(w):
            if policy == "pad":
                sy, sx = y - (h - th) // 2, x - (w - tw) // 2
                out[y, x] = scaled[sy, sx] if 0 <= sy < th and 0 <= sx < tw else fill
            else:
                out[y, x] = scaled[y + (th - h) // 2, x + (tw - w) // 2]
    return out


@pytest.mark.parametrize("policy", ["stretch", "pad", "crop"])
@pytest.mark.parametrize("shape", [(32, 64), (120, 160), (100, 40), (61, 97)])
def test_resize_policies_against_plain_loops(policy: str, shape: tuple[int, int]) -> None:
    from vpr_edge.features.resize import fit_to_input

    img = np.random.default_rng(shape[0]).integers(0, 256, shape + (3,), dtype=np.uint8)
    fill = np.array([124, 116, 104], np.uint8)
    got = fit_to_input(img, (80, 60), policy, fill)
    assert got.shape == (60, 80, 3) and got.dtype == np.uint8
    np.testing.assert_array_equal(got, naive_fit(img, (80, 60), policy, (124, 116, 104)))


def test_pad_masks_the_cells_that_see_only_padding() -> None:
    from vpr_edge.features.resize import content_cells

    size, grid = (320, 240), (20, 15)                  # 16-pixel cells
    for shape in [(32, 64), (240, 100), (120, 160), (10, 4000)]:
        got = content_cells(shape, size, grid).reshape(15, 20)
        canvas = naive_fit(np.full(shape + (3,), 255, np.uint8), size, "pad", (0, 0, 0))[..., 0] > 0
        centres = canvas[8::16, 8::16]                 # the image at each cell's centre pixel
        assert got.any()
        if centres.any():
            np.testing.assert_array_equal(got, centres)


@pytest.mark.slow
def test_resize_policy_recorded_in_the_map(tmp_path: Path, small_refs: Path) -> None:
    """build-map --resize pad: the map records it, its queries go through it; old maps (no record) stretch."""
    from vpr_edge.features.cnn import FeatureExtractor
    from vpr_edge.resources import LARGE_MODEL_FILE, bundled_model

    BUNDLED_MODEL = bundled_model(LARGE_MODEL_FILE)

    out = tmp_path / "pad.npz"
    res = CliRunner().invoke(app, ["build-map", str(small_refs), "-o", str(out), "--resize", "pad",
                                   "--components", "4", "--model", str(BUNDLED_MODEL)])
    assert res.exit_code == 0, res.output
    pm = load_map(out)
    assert pm.features == {"name": "cnn", "params": {"resize": "pad"}}
    front = map_front_end(pm, out)
    assert front.resize == "pad"                                       # type: ignore[attr-defined]
    wide = np.full((32, 64, 3), 200, np.uint8)                         # 2:1 into the model's 4:3: bands padded
    x = front.preprocess(wide)                                         # type: ignore[attr-defined]
    assert np.abs(x[:, :30]).max() < 0.03 and np.abs(x[:, 40:200]).min() > 0.5
    _, mask = front.local([wide, np.full((240, 320, 3), 9, np.uint8)])    # type: ignore[attr-defined]
    assert mask is not None and mask[0].sum() == 20 * 10 and mask[1].all()  # 2:1 into 4:3: 10 of 15 rows
    old = PlaceMap(pm.stored, pm.names, pm.encoder, pm.meta | {"features": {"name": "cnn", "params": {}}})
    assert map_front_end(old, out).resize == "stretch"                      # type: ignore[attr-defined]
    assert FeatureExtractor(BUNDLED_MODEL).describe() == {"name": "cnn", "params": {"resize": "stretch"}}
