"""Bad input never costs work or data: every command against a table of bad inputs.

For each case: exit code 2, exactly one ``vpr-edge: error:`` line on stderr naming the file and the problem
(warnings may precede it), no traceback, and every file in the workspace byte-identical afterwards with no
file added. Commands run in-process (typer's CliRunner) so the matrix stays fast; the cases that need a real
process (a full disk behind stdout, timing of the early output check) run one.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from helpers import run, write_bag
from vpr_edge.cli import app
from vpr_edge.errors import InputError, VprError
from vpr_edge.resources import bundled_model, sample_folder
from vpr_edge.map import MAP_SCHEMA
from vpr_edge.calibration import CALIBRATION_SCHEMA
from vpr_edge.encoders.base import CODEBOOK_SCHEMA
from vpr_edge.files.npz import read_npz, write_npz
from vpr_edge.evaluation.truth import write_ground_truth

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def ws(tmp_path_factory: pytest.TempPathFactory, small_refs: Path, small_queries: Path) -> Path:
    """A workspace holding good and bad inputs of every kind, and outputs that already exist."""
    w = tmp_path_factory.mktemp("ws")
    shutil.copytree(small_refs, w / "refs")
    shutil.copytree(small_queries, w / "queries")
    res = CliRunner().invoke(app, ["build-map", str(w / "refs"), "-o", str(w / "good.npz"), "--components", "4",
                                   "--save-codebook", str(w / "cb.npz")])
    assert res.exit_code == 0, res.stderr
    (w / "empty").mkdir()
    (w / "a_folder.npz").mkdir()
    (w / "notes.txt").write_text("frame_index,frame\n0,a.jpg\n")
    (w / "empty.npz").write_bytes(b"")
    (w / "old_results.csv").write_text("frame_index,frame,ref_index,ref,score,lost\n0,a.jpg,3,b.jpg,9.0,0\n")
    (w / "old.npz").write_bytes(b"a previous map the user cares about")
    shutil.copy(bundled_model(), w / "model.onnx")
    (w / "fake.onnx").write_bytes(b"\x08\x07 not really a model")
    good = (w / "good.npz").read_bytes()
    (w / "truncated.npz").write_bytes(good[: len(good) // 2])
    arrays, meta = read_npz(w / "good.npz", "map", MAP_SCHEMA)
    write_npz(w / "schema0.npz", arrays, meta | {"schema": 0})
    write_npz(w / "schema_newer.npz", arrays, meta | {"schema": MAP_SCHEMA + 1})
    cb_arrays, cb_meta = read_npz(w / "cb.npz", "codebook", CODEBOOK_SCHEMA)
    write_npz(w / "cb_newer.npz", cb_arrays, cb_meta | {"schema": CODEBOOK_SCHEMA + 1})
    write_npz(w / "front_unknown.npz", arrays, meta | {"features": meta["features"] | {"name": "nosuch"}})
    write_npz(w / "resize_unknown.npz", arrays,
              meta | {"features": meta["features"] | {"params": {**meta["features"].get("params", {}), "resize": "x"}}})
    np.savez(w / "pickled.npz", a=np.array([{"x": 1}], dtype=object))
    np.save(w / "sim.npy", np.random.default_rng(0).random((24, 24)))
    (w / "sim_bad.npy").write_bytes(b"\x93NUMPY garbage")
    np.save(w / "sim_huge.npy", 1e200 * np.random.default_rng(0).random((24, 24)))
    write_ground_truth(w / "gt.csv", [[i] for i in range(24)])
    write_ground_truth(w / "gt_short.csv", [[i] for i in range(10)])
    (w / "gt_bad.csv").write_text("query,references\n0,zero\n")

    for name, edit in {"refs_corrupt": "garbage", "refs_tiny": "tiny"}.items():
        shutil.copytree(small_refs, w / name)
        target = w / name / "0000003.jpg"
        if edit == "garbage":
            target.write_bytes(b"\xff\xd8 not a jpeg")
        else:
            cv2.imwrite(str(target), np.zeros((1, 1, 3), np.uint8))
    shutil.copytree(small_refs, w / "refs_mixed")   # 3 of the 24 frames from a camera of twice the resolution
    for f in sorted((w / "refs_mixed").glob("*.jpg"))[5::8]:
        cv2.imwrite(str(f), cv2.resize(cv2.imread(str(f)), (320, 240)))
    (w / "allbad").mkdir()
    for i in range(3):
        (w / "allbad" / f"{i:03d}.jpg").write_bytes(b"x")
    (w / "garbage.mp4").write_bytes(b"not a video, " * 160)   # fixed bytes: random ones decode now and then
    (w / "link_to_map.csv").symlink_to(w / "good.npz")
    os.link(w / "gt.csv", w / "gt_hard.csv")
    (w / "loop").symlink_to(w / "loop")
    (w / "pos_short.csv").write_text("x,y\n0,0\n1,0\n")
    (w / "pos_two.csv").write_text("x,y,lat,lon\n" + "0,0,1,1\n" * 24)
    (w / "pos_bad.csv").write_text("x,y\n" + "0,north\n" * 24)
    (w / "stamps_short.csv").write_text("frame,stamp\n0000000.jpg,1.0\n")
    (w / "track.gpx").write_text("<gpx></gpx>")
    try:
        write_bag(w / "d.bag", sorted(small_queries.glob("*.jpg"))[:2], "ros1")
    except ImportError:   # no rosbags (the ros extra): a file of the name, for the cases that read no bag
        (w / "d.bag").write_bytes(b"#ROSBAG V2.0\nnot written: rosbags is not installed")
    # damaged or hostile maps: metadata of the wrong shape, non-finite values, a compressed member
    for name, edit in {"meta_names": {"names": 5}, "meta_features": {"features": [1, 2]},
                       "meta_encoding": {"encoding": {"name": ["ifv"], "params": {}}},
                       "meta_storage": {"storage": 8}, "meta_alpha": {"schema": 2, "alpha": "high"}}.items():
        write_npz(w / f"{name}.npz", arrays, meta | edit)
    write_npz(w / "nan_scale.npz", arrays | {"encodings_scale": np.full_like(arrays["encodings_scale"], np.nan)}, meta)
    write_npz(w / "nan_codebook.npz", arrays | {"encoder_gmm_means": arrays["encoder_gmm_means"] * np.nan}, meta)
    np.savez_compressed(w / "compressed.npz", **arrays, __meta__=np.array(__import__("json").dumps(meta)))
    np.savez(w / "meta_list.npz", **arrays, __meta__=np.array("[1, 2, 3]"))
    # calibrations of the stream modes: one of schema 1 (no line), one whose line falls as its thresholds rise
    curve = {"scores": [0.0, 2.0], "confidence": [0.2, 0.9], "n": 24, "tolerance": 1}
    for name, schema, extra in (("cal_v1", 1, {}), ("cal_badline", 2, {"line": {"scores": [1.0, 2.0],
                                                                               "precision": [0.9, 0.8]}}),
                                ("cal_short", 2, {"line": {"scores": [1.0, 2.0], "precision": [0.8, 0.9]}}),
                                ("cal_newer", CALIBRATION_SCHEMA + 1, {})):
        (w / f"{name}.json").write_text(__import__("json").dumps(
            {"kind": "calibration", "schema": schema, "source": "test", "method": "logistic",
             "modes": {"stream": curve | extra, "stream-rules": curve | extra}}))
    return w


@dataclass(frozen=True)
class Case:
    id: str
    argv: str                 # {w} is the workspace
    needles: tuple[str, ...]  # all must appear in the error line
    env: tuple[tuple[str, str], ...] = ()
    hide: tuple[str, ...] = ()  # modules made unimportable (a missing extra)
    needs: tuple[str, ...] = ()  # modules the case needs installed (skipped without them)


BM = "build-map {w}/refs -o {w}/out.npz --components 4"
LOC = "localize -m {w}/good.npz -s {w}/queries"
RULES = LOC + " --mode stream-rules"   # the rule-based matcher, whose parameters the cases below refuse
EV = "evaluate --similarity {w}/sim.npy --gt {w}/gt.csv --modes single"

CASES = [
    Case("loc-map-unknown-front-end", "localize -m {w}/front_unknown.npz -s {w}/queries",
         ("front_unknown.npz", "front end 'nosuch'")),
    Case("loc-map-unknown-resize", "localize -m {w}/resize_unknown.npz -s {w}/queries",
         ("resize_unknown.npz", "resize policy 'x'")),
    # build-map: inputs
    Case("bm-refs-missing", "build-map {w}/nope -o {w}/out.npz", ("nope", "not a folder")),
    Case("bm-refs-empty", "build-map {w}/empty -o {w}/out.npz", ("empty", "no images")),
    Case("bm-refs-is-file", "build-map {w}/notes.txt -o {w}/out.npz", ("notes.txt", "not a folder")),
    Case("bm-ref-corrupt", "build-map {w}/refs_corrupt -o {w}/old.npz --components 4",
         ("0000003.jpg", "cannot decode")),
    Case("bm-ref-1x1", "build-map {w}/refs_tiny -o {w}/old.npz --components 4", ("0000003.jpg", "1x1", "too small")),
    Case("bm-refs-mixed-sizes-strict", "build-map {w}/refs_mixed -o {w}/old.npz --components 4 --strict",
         ("refs_mixed: 3 of 24 frames are 320x240, the rest 160x120 (e.g. ", "refs_mixed/0000005.jpg)",
          "--strict refuses frames of mixed sizes")),
    # build-map: outputs (checked before any extraction)
    Case("bm-out-proc", BM.replace("{w}/out.npz", "/proc/vpr-edge.npz"), ("/proc/vpr-edge.npz", "not writable")),
    Case("bm-out-no-folder", BM.replace("{w}/out.npz", "{w}/nodir/m.npz"), ("nodir", "does not exist")),
    Case("bm-out-is-folder", BM.replace("{w}/out.npz", "{w}/a_folder.npz"), ("a_folder.npz", "is a folder")),
    Case("bm-codebook-out-is-folder", BM + " --save-codebook {w}/a_folder.npz", ("a_folder.npz", "is a folder")),
    Case("bm-codebook-same-as-out", "build-map {w}/refs -o {w}/old.npz --save-codebook {w}/old.npz",
         ("old.npz", "same file")),
    # build-map: models, codebooks, extras, option combinations
    Case("bm-model-missing", BM + " --model {w}/none.onnx", ("none.onnx", "not found")),
    Case("bm-model-not-onnx", BM + " --model {w}/fake.onnx", ("fake.onnx", "not a loadable ONNX model")),
    Case("bm-model-env-missing", BM, ("gone.onnx", "VPR_EDGE_MODEL"), env=(("VPR_EDGE_MODEL", "{w}/gone.onnx"),)),
    Case("bm-model-env-not-model", BM, ("notes.txt", "not a loadable ONNX model"),
         env=(("VPR_EDGE_MODEL", "{w}/notes.txt"),)),
    Case("bm-codebook-missing", "build-map {w}/refs -o {w}/out.npz --codebook {w}/nocb.npz",
         ("nocb.npz", "no such file")),
    Case("bm-codebook-is-map", "build-map {w}/refs -o {w}/out.npz --codebook {w}/good.npz",
         ("good.npz", "not a vpr-edge codebook", "it is a vpr-edge map")),
    Case("bm-codebook-text", "build-map {w}/refs -o {w}/out.npz --codebook {w}/notes.txt",
         ("notes.txt", "not a vpr-edge codebook", "text file")),
    Case("bm-codebook-newer", "build-map {w}/refs -o {w}/out.npz --codebook {w}/cb_newer.npz",
         ("cb_newer.npz: made by a newer vpr-edge", f"(codebook schema {CODEBOOK_SCHEMA + 1}, this one reads up "
          f"to {CODEBOOK_SCHEMA}): upgrade vpr-edge")),
    Case("bm-codebook-and-fit-options", "build-map {w}/refs -o {w}/out.npz --codebook {w}/cb.npz --components 8",
         ("--components", "cb.npz")),
    Case("bm-fit-iterations-and-codebook", "build-map {w}/refs -o {w}/out.npz --codebook {w}/cb.npz --fit-iterations 5",
         ("--fit-iterations", "cb.npz")),
    Case("bm-append-missing-map", "build-map {w}/refs -o {w}/nomap.npz --append", ("nomap.npz", "no such file")),
    Case("bm-append-not-a-map", "build-map {w}/refs -o {w}/notes.txt --append", ("notes.txt", "not a vpr-edge map")),
    Case("bm-append-alpha", "build-map {w}/refs -o {w}/good.npz --append --alpha 0.3", ("good.npz", "--alpha")),
    Case("bm-append-codebook", "build-map {w}/refs -o {w}/good.npz --append --codebook {w}/cb.npz",
         ("cb.npz", "--append")),
    Case("bm-no-sklearn", BM, ("scikit-learn", "vpr-edge[fit]"), hide=("sklearn",)),
    # build-map: front ends, encodings, SVM
    Case("bm-features-model", BM + " --features hog --model {w}/model.onnx", ("model.onnx", "hog", "takes no model")),
    Case("bm-keypoints-none", BM + " --features sift-kp --encoding none", ("sift-kp", "fixed grid")),
    Case("bm-codebook-other-encoding", "build-map {w}/refs -o {w}/out.npz --codebook {w}/cb.npz --encoding vlad",
         ("cb.npz", "encoding ifv", "--encoding vlad")),
    Case("bm-codebook-other-front-end", "build-map {w}/refs -o {w}/out.npz --codebook {w}/cb.npz --features sift",
         ("cb.npz", "fitted on cnn descriptors", "sift")),
    Case("bm-positions-rows", BM + " --positions {w}/pos_short.csv", ("pos_short.csv", "2 positions but 24")),
    Case("bm-positions-two-frames", BM + " --positions {w}/pos_two.csv", ("pos_two.csv", "two frames")),
    Case("bm-positions-unparsable", BM + " --positions {w}/pos_bad.csv", ("pos_bad.csv", "'north' is not a number")),
    Case("bm-positions-missing", BM + " --positions {w}/nopos.csv", ("nopos.csv", "cannot read positions")),
    Case("bm-append-positions-to-plain-map", "build-map again={w}/refs -o {w}/good.npz --append --positions {w}/pos_two.csv",
         ("good.npz", "no positions", "--positions cannot be given to --append")),   # before the file is read
    Case("loc-bag-no-rosbags", "localize -m {w}/good.npz -s {w}/d.bag --topic /camera/image",
         ("d.bag", "vpr-edge[ros]"), hide=("rosbags",)),
    Case("loc-bag-wrong-topic", "localize -m {w}/good.npz -s {w}/d.bag --topic /gps/fix", ("d.bag", "NavSatFix"),
         needs=("rosbags",)),
    Case("bm-gpx-no-gpxpy", BM + " --positions {w}/track.gpx --timestamps {w}/stamps_short.csv",
         ("track.gpx", "vpr-edge[geo]"), hide=("gpxpy",)),
    Case("bm-exif-no-exifread", BM + " --positions exif", ("exifread", "vpr-edge[geo]"), hide=("exifread",)),
    Case("bm-timestamps-without-gpx", BM + " --timestamps {w}/stamps_short.csv", ("stamps_short.csv", "TRACK.gpx")),
    Case("ev-plot-matrix-is-the-similarity", EV + " --plot-matrix {w}/sim.npy", ("sim.npy", "--plot-matrix", "an input")),
    Case("ev-plot-route-trailing-slash", EV + " --plot-route {w}/figs/", ("figs/", "is a folder")),
    Case("ev-topic-without-a-bag", "evaluate --map {w}/good.npz --queries {w}/queries --gt {w}/gt.csv --topic /cam",
         ("--topic applies to a ROS bag",)),
    Case("loc-topic-without-a-bag", LOC + " --topic /cam", ("--topic applies to a ROS bag",)),
    Case("ev-calibration-out-is-gt", EV + " --save-calibration {w}/gt.csv", ("gt.csv", "an input")),
    Case("loc-calibration-not-json", LOC + " --calibration {w}/gt.csv", ("gt.csv", "not a vpr-edge calibration")),
    Case("ev-calibration-missing", EV + " --calibration {w}/nocal.json", ("nocal.json", "cannot read the calibration")),
    Case("ev-calibration-not-json", EV + " --calibration {w}/gt.csv", ("gt.csv", "not a vpr-edge calibration")),
    Case("loc-precision-int8-no-form", LOC + " --model {w}/model.onnx --precision int8",
         ("model.onnx", "no int8 form")),
    Case("loc-timestamps-short", LOC + " --timestamps {w}/stamps_short.csv", ("stamps_short.csv", "no stamp for 23")),
    Case("loc-timestamps-video", "localize -m {w}/good.npz -s {w}/garbage.mp4 --timestamps {w}/stamps_short.csv",
         ("--timestamps applies to a folder",)),
    Case("bm-append-svm", "build-map {w}/refs -o {w}/good.npz --append --svm", ("good.npz", "--append", "--svm")),
    Case("bm-append-resize", "build-map {w}/refs -o {w}/good.npz --append --resize pad",
         ("good.npz", "--append", "--resize")),
    Case("bm-resize-handcrafted", "build-map {w}/refs -o {w}/h.npz --features hog --resize crop",
         ("--resize", "cnn", "hog")),
    Case("bm-svm-no-sklearn", "build-map {w}/refs -o {w}/out.npz --codebook {w}/cb.npz --svm",
         ("scikit-learn", "vpr-edge[fit]"), hide=("sklearn",)),
    # localize
    Case("loc-map-missing", "localize -m {w}/none.npz -s {w}/queries", ("none.npz", "no such file")),
    Case("loc-map-empty", "localize -m {w}/empty.npz -s {w}/queries", ("empty.npz", "not a vpr-edge map", "empty")),
    Case("loc-map-text", "localize -m {w}/notes.txt -s {w}/queries", ("notes.txt", "not a vpr-edge map", "text")),
    Case("loc-map-csv", "localize -m {w}/old_results.csv -s {w}/queries", ("old_results.csv", "not a vpr-edge map")),
    Case("loc-map-onnx", "localize -m {w}/model.onnx -s {w}/queries", ("model.onnx", "not a vpr-edge map", "ONNX")),
    Case("loc-map-npy", "localize -m {w}/sim.npy -s {w}/queries", ("sim.npy", "not a vpr-edge map", ".npy")),
    Case("loc-map-folder", "localize -m {w}/a_folder.npz -s {w}/queries", ("a_folder.npz", "not a vpr-edge map")),
    Case("loc-map-truncated", "localize -m {w}/truncated.npz -s {w}/queries",
         ("truncated.npz", "truncated or corrupt")),
    Case("loc-map-pickled", "localize -m {w}/pickled.npz -s {w}/queries", ("pickled.npz", "pickled")),
    Case("loc-map-codebook", "localize -m {w}/cb.npz -s {w}/queries", ("cb.npz", "it is a vpr-edge codebook")),
    Case("loc-map-schema0", "localize -m {w}/schema0.npz -s {w}/queries", ("schema0.npz", "schema version 0",
                                                                          "rebuild it")),
    Case("loc-map-newer", "localize -m {w}/schema_newer.npz -s {w}/queries",
         (f"schema_newer.npz: made by a newer vpr-edge (map schema {MAP_SCHEMA + 1}, this one reads up to "
          f"{MAP_SCHEMA}): upgrade vpr-edge",)),
    Case("info-map-newer", "info {w}/schema_newer.npz", ("schema_newer.npz: made by a newer vpr-edge",
                                                        "upgrade vpr-edge")),
    Case("loc-calibration-newer", LOC + " --calibration {w}/cal_newer.json",
         (f"cal_newer.json: made by a newer vpr-edge (calibration schema {CALIBRATION_SCHEMA + 1}, this one "
          f"reads up to {CALIBRATION_SCHEMA}): upgrade vpr-edge",)),
    Case("loc-stream-missing", "localize -m {w}/good.npz -s {w}/nope", ("nope", "no such folder")),
    Case("loc-stream-empty", "localize -m {w}/good.npz -s {w}/empty", ("empty", "no images")),
    Case("loc-stream-text", "localize -m {w}/good.npz -s {w}/notes.txt", ("notes.txt", "not a folder of images")),
    Case("loc-stream-garbage-video", "localize -m {w}/good.npz -s {w}/garbage.mp4 -o {w}/old_results.csv",
         ("garbage.mp4",)),
    Case("loc-stream-all-corrupt", "localize -m {w}/good.npz -s {w}/allbad -o {w}/old_results.csv",
         ("allbad", "none of its frames")),
    Case("loc-camera-missing", "localize -m {w}/good.npz -s 7", ("7", "cannot open camera")),
    Case("loc-device-missing", "localize -m {w}/good.npz -s /dev/video9", ("/dev/video9", "cannot open camera")),
    Case("loc-rtsp-unreachable", "localize -m {w}/good.npz -s rtsp://127.0.0.1:9/none -o {w}/old_results.csv",
         ("rtsp://127.0.0.1:9/none", "cannot open stream")),
    Case("loc-out-proc", LOC + " -o /proc/results.csv", ("/proc/results.csv", "not writable")),
    Case("loc-out-no-folder", LOC + " -o {w}/nodir/r.csv", ("nodir", "does not exist")),
    Case("loc-out-is-folder", LOC + " -o {w}/a_folder.npz", ("a_folder.npz", "is a folder")),
    Case("loc-model-other", LOC + " --model {w}/fake.onnx", ("fake.onnx", "not a loadable ONNX model")),
    Case("loc-model-env-missing", LOC, ("gone.onnx", "VPR_EDGE_MODEL"), env=(("VPR_EDGE_MODEL", "{w}/gone.onnx"),)),
    Case("loc-svm-without-svm", LOC + " --mode svm", ("good.npz", "build-map --svm")),
    Case("loc-format-contradicts-out", LOC + " --format jsonl -o {w}/old_results.csv", ("old_results.csv", "--format")),
    Case("loc-param-unknown", RULES + " --param speed=3", ("--param", "speed=3", "lock")),
    Case("loc-param-bad-value", RULES + " --param lock=high", ("--param", "lock=high", "not a number")),
    Case("loc-param-bad-hub", RULES + " --param hub=high", ("--param", "hub=high", "not a number")),
    Case("loc-param-confirm-refused", RULES + " --param confirm=0", ("--param", "confirm must be at least 1")),
    Case("loc-param-stuck-refused", RULES + " --param stuck=-1", ("--param", "stuck must be at least 0")),
    Case("loc-param-trust-refused", RULES + " --param trust=0", ("--param", "trust must be in (0, 1]")),
    Case("loc-param-refused", RULES + " --param decay=1.5", ("--param", "decay must be in (0, 1)")),
    Case("loc-param-still-refused", LOC + " --param still=1.5", ("--param", "still must be in [0, 1]")),
    Case("loc-param-of-another-mode", LOC + " --param open_ends=true", ("--param", "open_ends=true", "stream takes")),
    Case("loc-param-other-mode", LOC + " --mode single --param lock=3", ("--param", "single takes")),
    # outputs never alias inputs (following links), a trailing slash names a folder
    Case("loc-out-is-the-map", LOC + " -o {w}/good.npz", ("good.npz", "--out", "an input")),
    Case("loc-out-links-to-the-map", LOC + " -o {w}/link_to_map.csv", ("link_to_map.csv", "an input")),
    Case("loc-out-inside-the-stream", LOC + " -o {w}/queries/r.csv", ("r.csv", "inside the input folder")),
    Case("loc-out-trailing-slash", LOC + " -o {w}/results/", ("results/", "is a folder")),
    Case("bm-out-is-a-reference", "build-map {w}/refs -o {w}/refs/0000005.jpg", ("0000005.jpg", "inside the input")),
    Case("bm-out-inside-refs", "build-map {w}/refs -o {w}/refs/route.npz", ("route.npz", "inside the input folder")),
    Case("bm-out-is-the-codebook", "build-map {w}/refs -o {w}/cb.npz --codebook {w}/cb.npz", ("cb.npz", "an input")),
    Case("bm-codebook-trailing-slash", BM + " --save-codebook {w}/cbs/", ("cbs/", "is a folder")),
    Case("ev-json-is-the-gt", EV + " --json {w}/gt.csv", ("gt.csv", "--json", "an input")),
    Case("ev-json-is-the-similarity", EV + " --json {w}/sim.npy", ("sim.npy", "an input")),
    Case("ev-json-hard-link-to-gt", EV + " --json {w}/gt_hard.csv", ("gt_hard.csv", "an input")),
    Case("loc-out-link-loop", LOC + " -o {w}/loop", ("loop", "loop of symbolic links")),
    Case("loc-min-confidence-nan", LOC + " --min-confidence nan", ("--min-confidence nan", "finite")),
    Case("ev-min-confidence-inf", EV + " --min-confidence inf", ("--min-confidence inf", "finite")),
    Case("loc-target-precision-one", LOC + " --mode stream --target-precision 1", ("--target-precision 1",
                                                                                         "between 0 and 1")),
    Case("loc-target-precision-on-stream", RULES + " --target-precision 0.99", ("--target-precision 0.99",
                                                                           "not the probability", "--min-confidence")),
    Case("ev-target-precision-negative", EV + " --target-precision -0.5", ("--target-precision -0.5", "between 0 and 1")),
    Case("loc-target-precision-calibration-without-line",
         RULES + " --calibration {w}/cal_v1.json --target-precision 0.99",
         ("--target-precision 0.99", "not the probability", "--calibration")),
    Case("loc-target-precision-beyond-the-drive", LOC + " --calibration {w}/cal_short.json --target-precision 0.98",
         ("--target-precision 0.98", "cal_short.json", "does not show that precision")),
    Case("loc-calibration-line-falls", LOC + " --calibration {w}/cal_badline.json", ("cal_badline.json", "line",
                                                                                     "rising")),
    Case("ev-answers-is-the-gt", EV + " --answers {w}/gt.csv", ("gt.csv", "--answers", "an input")),
    Case("loc-threads-absurd", LOC + " --threads 100000", ("--threads 100000", "per core")),
    Case("ev-json-and-similarity-out", EV + " --json {w}/x.out --save-similarity {w}/x.out", ("x.out", "same file")),
    # damaged or hostile maps
    Case("loc-map-names-not-a-list", "localize -m {w}/meta_names.npz -s {w}/queries", ("meta_names.npz", "'names'")),
    Case("loc-map-features-a-list", "localize -m {w}/meta_features.npz -s {w}/queries", ("meta_features.npz", "'features'")),
    Case("loc-map-encoding-name", "localize -m {w}/meta_encoding.npz -s {w}/queries", ("meta_encoding.npz", "'encoding'")),
    Case("loc-map-storage-number", "localize -m {w}/meta_storage.npz -s {w}/queries", ("meta_storage.npz", "'storage'")),
    Case("loc-map-alpha-text", "localize -m {w}/meta_alpha.npz -s {w}/queries", ("meta_alpha.npz", "'alpha'")),
    Case("loc-map-meta-a-list", "localize -m {w}/meta_list.npz -s {w}/queries", ("meta_list.npz", "metadata")),
    Case("loc-map-nan-scale", "localize -m {w}/nan_scale.npz -s {w}/queries", ("nan_scale.npz", "NaN")),
    Case("loc-map-nan-codebook", "localize -m {w}/nan_codebook.npz -s {w}/queries", ("nan_codebook.npz", "NaN")),
    Case("loc-map-compressed", "localize -m {w}/compressed.npz -s {w}/queries", ("compressed.npz", "compressed")),
    Case("info-map-names-not-a-list", "info {w}/meta_names.npz", ("meta_names.npz", "'names'")),
    # info
    Case("info-missing", "info {w}/none.npz", ("none.npz", "no such file")),
    Case("info-text", "info {w}/notes.txt", ("notes.txt", "not a vpr-edge map")),
    Case("info-codebook", "info {w}/cb.npz", ("cb.npz", "it is a vpr-edge codebook")),
    # evaluate
    Case("ev-no-source", "evaluate --gt {w}/gt.csv", ("give one source",)),
    Case("ev-two-sources", EV + " --map {w}/good.npz --queries {w}/queries", ("give one source",)),
    Case("ev-two-truths", EV + " --gt-positions {w}/notes.txt {w}/notes.txt", ("ground truth",)),
    Case("ev-sim-missing", "evaluate --similarity {w}/none.npy --gt {w}/gt.csv", ("none.npy",)),
    Case("ev-sim-corrupt", "evaluate --similarity {w}/sim_bad.npy --gt {w}/gt.csv", ("sim_bad.npy", "not a readable")),
    Case("ev-sim-huge", "evaluate --similarity {w}/sim_huge.npy --gt {w}/gt.csv", ("sim_huge.npy", "overflow")),
    Case("ev-gt-missing", "evaluate --similarity {w}/sim.npy --gt {w}/nogt.csv", ("nogt.csv",)),
    Case("ev-gt-malformed", "evaluate --similarity {w}/sim.npy --gt {w}/gt_bad.csv", ("gt_bad.csv",)),
    Case("ev-gt-rows", "evaluate --similarity {w}/sim.npy --gt {w}/gt_short.csv", ("gt_short.csv", "rows")),
    Case("ev-svm-without-map", EV.replace("single", "svm"), ("mode svm needs --map",)),
    Case("ev-svm-map-without-svm", "evaluate --map {w}/good.npz --queries {w}/queries --gt {w}/gt.csv --modes svm",
         ("good.npz", "build-map --svm")),
    Case("ev-unknown-mode", EV.replace("single", "nosuch"), ("nosuch", "unknown matcher")),
    Case("ev-json-is-folder", EV + " --json {w}/a_folder.npz", ("a_folder.npz", "is a folder")),
    Case("ev-json-proc", EV + " --json /proc/r.json", ("/proc/r.json", "not writable")),
    Case("ev-plot-no-matplotlib", EV + " --plot {w}/pr.png", ("--plot", "matplotlib"), hide=("matplotlib",)),
    Case("ev-queries-vs-gt", "evaluate --map {w}/good.npz --queries {w}/queries --gt {w}/gt_short.csv",
         ("queries", "24 frames", "gt_short.csv")),
]


def _snapshot(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): (hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir")
            for p in sorted(folder.rglob("*"))}


@pytest.mark.slow
@pytest.mark.parametrize("case", CASES, ids=lambda c: c.id)
def test_bad_input(case: Case, ws: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    for module in case.needs:
        pytest.importorskip(module)
    for key, value in case.env:
        monkeypatch.setenv(key, value.format(w=ws))
    for module in case.hide:
        for name in [m for m in sys.modules if m == module or m.startswith(module + ".")]:
            monkeypatch.delitem(sys.modules, name)
        monkeypatch.setitem(sys.modules, module, None)  # import raises ImportError, as if not installed
    before = _snapshot(ws)
    res = CliRunner().invoke(app, case.argv.format(w=ws).split())
    assert res.exit_code == 2, (res.exit_code, res.stderr, res.exception)
    assert isinstance(res.exception, SystemExit), res.exception           # no traceback: a handled exit
    assert "Traceback" not in res.stderr
    lines = [ln for ln in res.stderr.splitlines() if ln.strip() and not ln.startswith("vpr-edge: warning:")]
    assert len(lines) == 1 and lines[0].startswith("vpr-edge: error: "), res.stderr
    for needle in case.needles:
        assert needle.format(w=ws) in lines[0], (needle, lines[0])
    assert _snapshot(ws) == before                                        # nothing changed, nothing added


def test_unwritable_out_fails_before_any_work() -> None:
    t0 = time.perf_counter()
    proc = run("build-map", str(sample_folder() / "ref"), "-o", "/proc/vpr-edge/m.npz")
    elapsed = time.perf_counter() - t0
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.strip().splitlines()[-1].startswith("vpr-edge: error: /proc/vpr-edge/m.npz")
    assert elapsed < 2.0, elapsed                      # the whole process, not only the check


def test_full_disk_behind_stdout(ws: Path) -> None:
    if not Path("/dev/full").exists():
        pytest.skip("no /dev/full here")
    with open("/dev/full", "w") as full:
        proc = subprocess.run([sys.executable, "-m", "vpr_edge", "localize", "-m", str(ws / "good.npz"),
                               "-s", str(ws / "queries")], stdout=full, stderr=subprocess.PIPE, text=True,
                              timeout=300)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("vpr-edge: error:")]
    assert errors == ["vpr-edge: error: stdout: cannot write results (No space left on device)"], proc.stderr


@pytest.mark.parametrize("suffix", [".csv", ".jsonl", ".mcap"])
def test_full_disk_keeps_the_older_log_and_the_new_lines(ws: Path, tmp_path: Path, suffix: str,
                                                         full_disk: Callable[[str, bytes], Path]) -> None:
    """A disk that fills mid-stream: exit 2 in one line, the older log byte for byte, the lines in NAME.part."""
    older = b"an older, complete log\n" * 600                              # 13.8 kB
    out = full_disk(f"results{suffix}", older)
    queries = tmp_path / "queries"                                       # a stream longer than the room
    queries.mkdir()
    frames = sorted((ws / "queries").iterdir()) * 4
    for i, f in enumerate(frames):
        shutil.copy(f, queries / f"{i:07d}{f.suffix}")
    proc = subprocess.run([sys.executable, "-m", "vpr_edge", "localize", "-m", str(ws / "good.npz"), "-s",
                           str(queries), "-o", str(out)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("vpr-edge: error:")]
    assert len(errors) == 1 and "No space left on device" in errors[0], proc.stderr
    assert out.read_bytes() == older
    if suffix == ".mcap":
        assert f"{out}.part: the recording of a run that failed; {out} left as it was" in proc.stderr
        assert Path(f"{out}.part").stat().st_size > 0
        return
    assert f"kept in {out}.part (the run failed); {out} left as it was" in proc.stderr, proc.stderr
    text = Path(f"{out}.part").read_text()
    assert text.endswith("\n") and len(text.splitlines()) > 10
    if suffix == ".jsonl":
        assert [json.loads(ln)["frame_index"] for ln in text.splitlines()] == list(range(len(text.splitlines())))


def test_warnings_for_ignored_input(ws: Path, tmp_path: Path) -> None:
    frames = tmp_path / "frames"
    shutil.copytree(ws / "queries", frames)
    (frames / "README.txt").write_text("not a frame")
    (frames / "0000010.jpg").unlink()
    cv2.imwrite(str(frames / "0000010.png"), np.zeros((2, 2, 3), np.uint8))
    res = CliRunner().invoke(app, ["localize", "-m", str(ws / "good.npz"), "-s", str(frames)])
    assert res.exit_code == 0, res.stderr
    warnings = [ln for ln in res.stderr.splitlines() if ln.startswith("vpr-edge: warning:")]
    assert any("1 file(s) that are not images ignored (e.g. README.txt)" in w for w in warnings), warnings
    assert any("0000010.png" in w and "2x2" in w and "frame skipped" in w for w in warnings), warnings
    assert len(res.stdout.splitlines()) == 24                  # 23 frames + header


def _warnings(stderr: str, needle: str) -> list[str]:
    return [ln for ln in stderr.splitlines() if ln.startswith("vpr-edge: warning:") and needle in ln]


def test_mixed_frame_sizes_warned_or_refused(ws: Path, tmp_path: Path) -> None:
    """A folder of 160x120 frames with three at 320x240 builds with one warning naming the sizes, their counts
    and the first odd file; --strict refuses it in one line before writing anything."""
    out = tmp_path / "mixed.npz"
    res = CliRunner().invoke(app, ["build-map", str(ws / "refs_mixed"), "-o", str(out), "--codebook",
                                   str(ws / "cb.npz")])
    assert res.exit_code == 0 and out.is_file(), res.stderr
    assert _warnings(res.stderr, "frames are") == [
        f"vpr-edge: warning: {ws / 'refs_mixed'}: 3 of 24 frames are 320x240, the rest 160x120 (e.g. "
        f"{ws / 'refs_mixed' / '0000005.jpg'}); they are resized to the model's input, which matches less well"]
    strict = tmp_path / "strict.npz"
    res = CliRunner().invoke(app, ["build-map", str(ws / "refs_mixed"), "-o", str(strict), "--codebook",
                                   str(ws / "cb.npz"), "--strict"])
    assert res.exit_code == 2 and not strict.exists() and sorted(tmp_path.iterdir()) == [out], res.stderr
    assert res.stderr.splitlines()[-1].endswith("(e.g. " + str(ws / "refs_mixed" / "0000005.jpg") + "); --strict "
                                                "refuses frames of mixed sizes")
    res = CliRunner().invoke(app, ["build-map", str(ws / "refs"), "-o", str(strict), "--codebook", str(ws / "cb.npz"),
                                   "--strict"])   # frames of one size: --strict builds as without
    assert res.exit_code == 0 and strict.is_file() and not _warnings(res.stderr, "frames are"), res.stderr


def test_mixed_frame_sizes_in_a_bag(ws: Path, tmp_path: Path) -> None:
    """A bag's frames are sized once extracted: --strict refuses them before anything is written, naming the
    odd frame by its place in the bag."""
    pytest.importorskip("rosbags")
    frames = tmp_path / "frames"
    frames.mkdir()
    for i, f in enumerate(sorted((ws / "refs").glob("*.jpg"))[:8]):
        image = cv2.imread(str(f))
        cv2.imwrite(str(frames / f.name), cv2.resize(image, (320, 240)) if i == 3 else image)
    bag = write_bag(tmp_path / "mixed.bag", sorted(frames.glob("*.jpg")), "ros1")
    out = tmp_path / "bag.npz"
    res = CliRunner().invoke(app, ["build-map", str(bag), "--topic", "/camera/image", "-o", str(out), "--codebook",
                                   str(ws / "cb.npz"), "--strict"])
    assert res.exit_code == 2 and not out.exists(), res.stderr
    assert res.stderr.splitlines()[-1] == (f"vpr-edge: error: {bag}: 1 of 8 frames are 320x240, the rest 160x120 "
                                           "(e.g. mixed.bag#3); --strict refuses frames of mixed sizes")


def test_frame_sizes_of_three_kinds(tmp_path: Path, small_refs: Path) -> None:
    """Frames of three sizes: the odd ones listed by size, most first, beside the size most frames have."""
    from vpr_edge.frames.images import check_frame_sizes

    files = sorted(small_refs.glob("*.jpg"))[:8]
    folder = tmp_path / "three"
    folder.mkdir()
    for i, f in enumerate(files):
        size = (640, 480) if i == 6 else (320, 240) if i in (2, 4) else None
        image = cv2.imread(str(f))
        cv2.imwrite(str(folder / f.name), cv2.resize(image, size) if size else image)
    listed = sorted(folder.iterdir())
    with pytest.raises(InputError) as e:
        check_frame_sizes(folder, listed, strict=True, names=[p.name for p in listed])
    assert str(e.value) == (f"{folder}: 3 of 8 frames are of 2 other sizes, 320x240 (2), 640x480 (1), the rest "
                            f"160x120 (e.g. {files[2].name}); strict refuses frames of mixed sizes")


def test_image_sizes_from_headers(tmp_path: Path) -> None:
    """Each image format listed is sized from its header as OpenCV decodes it, EXIF orientation included; a
    file that is not an image has no size."""
    from PIL import Image

    from vpr_edge.frames.headers import image_size
    from vpr_edge.frames.images import IMAGE_SUFFIXES, load_image

    image = np.random.default_rng(0).integers(0, 255, (37, 53, 3), np.uint8)
    for suffix in sorted(IMAGE_SUFFIXES):
        path = tmp_path / f"a{suffix}"
        assert cv2.imwrite(str(path), image[..., 0] if suffix == ".pgm" else image)
        assert image_size(path) == (53, 37), suffix
    for orientation in (1, 3, 6, 8):   # 6 and 8: a quarter turn, the sides swapped
        exif = Image.Exif()
        exif[0x0112] = orientation
        for suffix in (".jpg", ".png", ".webp"):
            path = tmp_path / f"o{orientation}{suffix}"
            Image.fromarray(image).save(path, exif=exif)
            assert image_size(path) == load_image(path).shape[1::-1], path.name
    (tmp_path / "not.jpg").write_bytes(b"\xff\xd8 not a jpeg")
    assert image_size(tmp_path / "not.jpg") is None and image_size(tmp_path / "none.png") is None


def test_greyscale_frames_warned_once(ws: Path, tmp_path: Path) -> None:
    """Greyscale frames given to a model that takes colour: one warning per command, naming the first such
    frame (single-channel files at build-map, three equal channels in a stream); colour frames say nothing."""
    refs = tmp_path / "grey_refs"
    refs.mkdir()
    for f in sorted((ws / "refs").glob("*.jpg")):
        cv2.imwrite(str(refs / f.name), cv2.cvtColor(cv2.imread(str(f)), cv2.COLOR_BGR2GRAY))   # one channel
    res = CliRunner().invoke(app, ["build-map", str(refs), "-o", str(tmp_path / "g.npz"), "--codebook",
                                   str(ws / "cb.npz")])
    assert res.exit_code == 0, res.stderr
    assert _warnings(res.stderr, "greyscale") == [
        f"vpr-edge: warning: {refs / '0000000.jpg'}: greyscale frame, but the model "
        f"{bundled_model().name} expects colour (RGB); greyscale frames match less well than colour ones"]
    stream = tmp_path / "some_grey"
    shutil.copytree(ws / "queries", stream)
    for name in ("0000004.jpg", "0000009.jpg"):   # three equal channels
        grey = cv2.cvtColor(cv2.imread(str(stream / name)), cv2.COLOR_BGR2GRAY)
        cv2.imwrite(str(stream / name), cv2.merge([grey, grey, grey]))
    res = CliRunner().invoke(app, ["localize", "-m", str(ws / "good.npz"), "-s", str(stream), "--mode", "single"])
    assert res.exit_code == 0, res.stderr
    warned = _warnings(res.stderr, "greyscale")
    assert len(warned) == 1 and warned[0].startswith(f"vpr-edge: warning: {stream / '0000004.jpg'}: greyscale frame"), \
        res.stderr
    res = CliRunner().invoke(app, ["localize", "-m", str(ws / "good.npz"), "-s", str(ws / "queries"), "--mode",
                                   "single"])
    assert res.exit_code == 0 and not _warnings(res.stderr, "greyscale"), res.stderr


def test_what_is_greyscale() -> None:
    """Three equal channels (or one) are greyscale; a frame of one shade (black) is not judged; the front ends
    that read grey themselves are not watched."""
    from vpr_edge.features import make_front_end
    from vpr_edge.frames.images import GreyFrames, is_greyscale

    rng = np.random.default_rng(0)
    grey = rng.integers(0, 255, (120, 160), np.uint8)
    assert is_greyscale(grey) and is_greyscale(np.dstack([grey] * 3))
    assert not is_greyscale(rng.integers(0, 255, (120, 160, 3), np.uint8))
    assert not is_greyscale(np.zeros((120, 160, 3), np.uint8))
    assert GreyFrames.of(make_front_end("hog")).colour is None
    assert GreyFrames.of(make_front_end("cnn")).colour == "RGB"


def test_files_from_a_newer_vpr_edge(tmp_path: Path) -> None:
    """A model whose metadata is of a newer schema says to upgrade vpr-edge (maps, codebooks and calibrations:
    the table above); an older one keeps its line."""
    from vpr_edge.features.cnn import MODEL_SCHEMA, _checked_info

    with pytest.raises(VprError) as e:
        _checked_info(Path("m.onnx"), json.dumps({"schema": MODEL_SCHEMA + 1}))
    assert str(e.value) == (f"m.onnx: made by a newer vpr-edge (model metadata schema {MODEL_SCHEMA + 1}, this one "
                            f"reads up to {MODEL_SCHEMA}): upgrade vpr-edge")
    with pytest.raises(VprError, match="model metadata schema 0 unsupported"):
        _checked_info(Path("m.onnx"), json.dumps({"schema": 0}))


@pytest.mark.slow
def test_small_images_warned_once(tmp_path: Path, ws: Path) -> None:
    frames = tmp_path / "small"
    frames.mkdir()
    for f in sorted((ws / "queries").iterdir())[:5]:
        cv2.imwrite(str(frames / (f.stem + ".png")), cv2.resize(cv2.imread(str(f)), (36, 28)))
    proc = run("localize", "-m", str(ws / "good.npz"), "-s", str(frames), "--mode", "single")
    assert proc.returncode == 0, proc.stderr
    warned = [ln for ln in proc.stderr.splitlines() if "upsampled more than 4x" in ln]
    assert len(warned) == 1 and "36x28" in warned[0], proc.stderr


def test_option_values_refused_by_the_parser() -> None:
    """Values the option parser refuses (an unknown --storage, a negative count) get the parser's usage
    message (three lines: usage, hint, error), exit code 2, no traceback."""
    for argv in (["build-map", "x", "-o", "y.npz", "--storage", "int4"], ["localize", "-m", "m", "-s", "s",
                                                                          "--mode", "nope"],
                 ["build-map", "x", "-o", "y.npz", "--fit-iterations", "0"],
                 ["localize", "-m", "m", "-s", "s", "--batch-size", "0"],
                 ["build-map", "x", "-o", "y.npz", "--resize", "squash"]):
        res = CliRunner().invoke(app, argv)
        assert res.exit_code == 2 and isinstance(res.exception, SystemExit), res.stderr
        assert "Traceback" not in res.stderr and argv[-2] in res.stderr.splitlines()[-1]


def test_help_and_version() -> None:
    runner = CliRunner()
    from vpr_edge import __version__

    res = runner.invoke(app, ["--version"])
    assert res.exit_code == 0 and res.stdout.strip() == f"vpr-edge {__version__}"
    for cmd in ("build-map", "localize", "evaluate", "info"):
        res = runner.invoke(app, [cmd, "-h"], terminal_width=80, env={"COLUMNS": "80"})
        assert res.exit_code == 0 and "Usage:" in res.stdout, cmd
        assert "…" not in res.stdout                                      # nothing cut off
        assert max(map(len, res.stdout.splitlines())) <= 80, cmd


def test_outputs_follow_the_umask(ws: Path, tmp_path: Path) -> None:
    old = os.umask(0o027)
    try:
        res = CliRunner().invoke(app, ["localize", "-m", str(ws / "good.npz"), "-s", str(ws / "queries"),
                                       "--mode", "single", "-o", str(tmp_path / "r.csv")])
    finally:
        os.umask(old)
    assert res.exit_code == 0, res.stderr
    assert (tmp_path / "r.csv").stat().st_mode & 0o777 == 0o640
    assert (ws / "good.npz").stat().st_mode & 0o777 == 0o666 & ~old


def test_vpr_edge_model_wins_over_the_recorded_model(ws: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("VPR_EDGE_MODEL", str(ws / "model.onnx"))      # the same model, another path: accepted
    res = CliRunner().invoke(app, ["localize", "-m", str(ws / "good.npz"), "-s", str(ws / "queries")])
    assert res.exit_code == 0 and len(res.stdout.splitlines()) == 25, res.stderr


@pytest.mark.parametrize("failure, code", [(KeyboardInterrupt(), 130),
                                           (OSError(5, "Input/output error", "/dev/video0"), 2)])
def test_stream_failing_part_way_keeps_earlier_results(ws: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                       failure: BaseException, code: int) -> None:
    """Ctrl-C or a camera that fails after some frames: the results are a log, the lines before it are kept,
    said in the summary, then the one line of what ended it. Ctrl-C, the user's stop, replaces the earlier
    run's file only now; a failure keeps both, the earlier file and the new lines in NAME.part."""
    from vpr_edge.api import Localizer

    real = Localizer.answers

    def failing(self, *args, **kwargs):
        for i, pair in enumerate(real(self, *args, **kwargs)):
            if i == 3:
                raise failure
            yield pair

    monkeypatch.setattr(Localizer, "answers", failing)
    out = tmp_path / "old_results.csv"
    out.write_text("the earlier run\n")
    before = _snapshot(ws)
    res = CliRunner().invoke(app, ["localize", "-m", str(ws / "good.npz"), "-s", str(ws / "queries"), "-o", str(out)])
    assert res.exit_code == code and isinstance(res.exception, SystemExit), (res.exit_code, res.stderr)
    last = res.stderr.strip().splitlines()[-1]
    assert last == "vpr-edge: interrupted" if code == 130 else last.startswith("vpr-edge: error: /dev/video0:")
    log = out if code == 130 else Path(f"{out}.part")
    assert "Traceback" not in res.stderr and f"3 lines kept in {log}" in res.stderr
    assert log.read_text().count("\n") == 4 and log.read_text().startswith("frame_index,")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted({"old_results.csv", log.name})
    if code != 130:
        assert out.read_text() == "the earlier run\n" and f"(the run failed); {out} left as it was" in res.stderr
    assert _snapshot(ws) == before
