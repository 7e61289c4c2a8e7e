"""The speed yardstick every timing is read against: one fp32 inference of the bundled 320x240 model on one
thread, measured in the same run as what it is compared with (a shared machine's speed drifts; ratios hold)."""
from __future__ import annotations

import os
import time

import numpy as np


def yardstick_ms(runs: int = 40) -> float:
    """Median ms of one fp32 inference of the bundled 320x240 model, batch 1, one onnxruntime thread (after
    a warm-up), with NumPy's BLAS held to one thread as localize --threads 1 does."""
    import onnxruntime as ort

    from vpr_edge.resources import LARGE_MODEL_FILE, bundled_model
    from vpr_edge.threads import use_threads

    use_threads(1)
    ort.set_default_logger_severity(3)
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    opts.log_severity_level = 3
    opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
    sess = ort.InferenceSession(str(bundled_model(LARGE_MODEL_FILE)), opts, providers=["CPUExecutionProvider"])
    inp = sess.get_inputs()[0]
    x = np.random.default_rng(0).standard_normal([1, *inp.shape[1:]]).astype(np.float32)
    for _ in range(3):
        sess.run(None, {inp.name: x})
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        sess.run(None, {inp.name: x})
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def chain_ms(map_path: str | os.PathLike[str], stream: str | os.PathLike[str]) -> float:
    """The whole per-frame chain's ms a frame once started: ``Localizer.run`` on one thread over the frames of
    ``stream`` (the first frame, which pays the start, excluded), to be read beside ``yardstick_ms``."""
    from vpr_edge.api import Localizer
    from vpr_edge.frames.images import open_stream

    loc = Localizer(map_path, threads=1)
    frames, _ = open_stream(stream)
    stamps = [time.perf_counter() for _ in loc.run(frames)]
    return 1e3 * (stamps[-1] - stamps[0]) / max(1, len(stamps) - 1)
