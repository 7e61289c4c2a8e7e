"""The model a cnn front end runs: the bundled input chosen by the camera's frame size (build-map, recorded
in the map), and the int8 form chosen by --precision and the CPU (features.choice)."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import pytest

from helpers import run
from vpr_edge.cli.common import flag
from vpr_edge.errors import InputError, VprError
from vpr_edge.features import choice
from vpr_edge.features.cnn import FeatureExtractor
from vpr_edge.map import load_map, map_front_end
from vpr_edge.resources import LARGE_MODEL_FILE, MODEL_FILES, SMALL_MODEL_FILE, bundled_model, int8_form


@pytest.mark.parametrize("size, expected", [((64, 32), SMALL_MODEL_FILE), ((160, 120), SMALL_MODEL_FILE),
                                            ((200, 150), SMALL_MODEL_FILE), ((320, 240), LARGE_MODEL_FILE),
                                            ((1920, 1080), LARGE_MODEL_FILE), ((319, 1000), SMALL_MODEL_FILE)])
def test_model_for_frame_never_upsamples_when_a_model_fits(size: tuple[int, int], expected: str) -> None:
    assert choice.model_for_frame(*size).name == expected
    # naive rule: the largest bundled input within the frame on both sides, else the smallest
    within = [s for s in MODEL_FILES if s[0] <= size[0] and s[1] <= size[1]]
    naive = max(within, key=lambda s: s[0] * s[1]) if within else min(MODEL_FILES, key=lambda s: s[0] * s[1])
    assert MODEL_FILES[naive] == expected


def test_bundled_int8_forms_name_their_source() -> None:
    for name in MODEL_FILES.values():
        fp32, int8 = FeatureExtractor(bundled_model(name)), FeatureExtractor(bundled_model(int8_form(name)))
        assert int8.source_fingerprint == fp32.fingerprint and fp32.source_fingerprint is None
        assert (int8.form, fp32.form) == ("int8", "fp32") and int8.size == fp32.size
        assert choice.bundled_for_sha256(fp32.fingerprint) == bundled_model(name)
    assert choice.bundled_for_sha256("0" * 64) is None


def test_choose_form_by_precision_and_cpu(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    fp32 = bundled_model(SMALL_MODEL_FILE)
    assert choice.choose_form(fp32, "fp32") == (fp32, "fp32: asked for")
    assert choice.choose_form(fp32, "int8")[0].name == int8_form(fp32.name)
    monkeypatch.setattr(choice, "int8_dot_product", lambda: "AVX512-VNNI")
    assert choice.choose_form(fp32, "auto") == (fp32.with_name(int8_form(fp32.name)), "int8: AVX512-VNNI")
    monkeypatch.setattr(choice, "int8_dot_product", lambda: None)
    path, why = choice.choose_form(fp32, "auto")
    assert path == fp32 and why.startswith("fp32:") and "no int8 dot-product" in why
    alone = tmp_path / "alone.onnx"                       # a model with no int8 form beside it
    shutil.copy(fp32, alone)
    with pytest.raises(VprError, match="no int8 form"):
        choice.choose_form(alone, "int8")
    with pytest.raises(VprError, match="^precision fp16: choose from") as wrong:   # the library's name
        choice.choose_form(fp32, "fp16")
    assert wrong.value.line(flag).startswith("--precision fp16: choose from")   # the CLI's


def test_cpu_flags_read_from_cpuinfo(monkeypatch: pytest.MonkeyPatch) -> None:
    for flags, expected in (({"avx2", "avx512_vnni"}, "AVX512-VNNI"), ({"avx2", "avx_vnni"}, "AVX-VNNI"),
                            ({"fp", "asimd", "asimddp"}, "ARM dotprod"), ({"avx2", "fma"}, None), (set(), None)):
        monkeypatch.setattr(choice, "_cpu_flags", lambda f=flags: f)
        choice.int8_dot_product.cache_clear()
        assert choice.int8_dot_product() == expected
    choice.int8_dot_product.cache_clear()


@pytest.mark.slow
def test_build_map_chooses_by_camera_and_localize_by_precision(tmp_path: Path, small_refs: Path,
                                                               small_queries: Path) -> None:
    """160x120 frames get the 160x120 model, 320x240 frames the 320x240 one (recorded); the int8 form of the
    map's model is accepted by precision int8, and a wrong model is still refused."""
    big = tmp_path / "big"
    big.mkdir()
    for f in sorted(small_refs.iterdir())[:8]:
        cv2.imwrite(str(big / f.name), cv2.resize(cv2.imread(str(f)), (320, 240)))
    for refs, model in ((small_refs, SMALL_MODEL_FILE), (big, LARGE_MODEL_FILE)):
        out = tmp_path / f"{refs.name}.npz"
        proc = run("build-map", refs, "-o", out, "--components", "4")
        assert proc.returncode == 0, proc.stderr
        pm = load_map(out)
        w, h = cv2.imread(str(sorted(refs.iterdir())[0])).shape[1::-1]
        assert pm.meta["model_file"] == model and pm.meta["model_choice"] == f"camera {w}x{h}: {model}"
        info = json.loads(run("info", out).stdout)
        assert info["bytes_per_place"] == 2 * 4 * 24 + 4                 # default PCA 24, int8 + row scale
    out = tmp_path / f"{small_refs.name}.npz"
    pm = load_map(out)
    assert map_front_end(pm, out).form == "fp32: asked for"            # the default precision
    fast = map_front_end(pm, out, precision="int8")
    assert fast.path.name == int8_form(SMALL_MODEL_FILE) and fast.form == "int8: asked for"
    given = map_front_end(pm, out, bundled_model(int8_form(SMALL_MODEL_FILE)))
    assert given.form == "int8: given"
    with pytest.raises(InputError, match="pass model with the map's model") as wrong:   # named as the library does
        map_front_end(pm, out, bundled_model(int8_form(LARGE_MODEL_FILE)))
    assert wrong.value.inputs == ("model",) and wrong.value.line(flag).endswith("pass --model with the map's model")
    for precision in ("fp32", "int8", "auto"):
        proc = run("localize", "-m", out, "-s", small_queries, "--precision", precision, "--mode", "single")
        assert proc.returncode == 0 and len(proc.stdout.splitlines()) == 25, proc.stderr
        said = [line for line in proc.stderr.splitlines() if "--precision auto" in line]
        assert len(said) == (precision == "auto"), proc.stderr     # what auto chose is said, on stderr
        if said:
            assert SMALL_MODEL_FILE.removesuffix(".onnx") in said[0] and ("int8: " in said[0] or "fp32: " in said[0])
    js = tmp_path / "e.json"
    gt = tmp_path / "gt.csv"
    gt.write_text("query,references\n" + "".join(f"{i},{i}\n" for i in range(24)))
    proc = run("evaluate", "--map", out, "--queries", small_queries, "--gt", gt, "--modes", "single",
               "--precision", "int8", "--json", js)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(js.read_text())["front_end"] == {"name": "cnn", "model": int8_form(SMALL_MODEL_FILE),
                                                       "form": "int8: asked for"}
    assert "model efficientnet_lite0_stage5_160x120.int8.onnx (int8: asked for)" in proc.stdout
    # --pca-dim 0: descriptors as they are (the thesis's codebook)
    proc = run("build-map", small_refs, "-o", tmp_path / "full.npz", "--components", "4", "--pca-dim", "0")
    assert proc.returncode == 0 and load_map(tmp_path / "full.npz").stored.shape[1] == 2 * 4 * 112


@pytest.mark.parametrize("name", sorted(MODEL_FILES.values()))
def test_bundled_int8_forms_keep_sums_in_16_bits(name: str) -> None:
    """The bundled int8 forms are U8S8 with 7-bit weights: x86 without VNNI then computes the same integers
    as VNNI and ARM (U8U8's x86 kernels without VNNI do not; docs/decisions.md, "fp32 by default")."""
    sibling = choice.int8_sibling(bundled_model(name))
    assert sibling is not None
    assert FeatureExtractor(sibling).info["quantization"]["scheme"].startswith("static QOperator, U8S8 reduce_range")
