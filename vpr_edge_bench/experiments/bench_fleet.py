"""A build on Ray against the plain build: its time, and the two maps compared byte for byte.

What a build on Ray costs against the plain build (docs/results.md, "Maps of several drives"): the same
references built by ``map.make`` without and with ``--ray``, each timed as a whole (start-up included), the
two maps compared byte for byte.

    python -m vpr_edge_bench bench-fleet --refs ../shared/datasets/nordland-dev/ref --ray local

Both builds fit the codebook in this process on the same sample; with ``--codebook-first`` a codebook is fitted
once first and both builds reuse it, so that every reference goes through the per-frame work (on Ray: every
one on the workers). Prints seconds, frames a second, and for the Ray build frames a second per worker CPU.
"""
from __future__ import annotations

import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vpr_edge.map import load_map
from vpr_edge.map.make import BuildOptions, plan_map, write_map
from vpr_edge_bench.runner import parser, run_checked


def timed_build(refs: Path, out: Path, options: BuildOptions) -> float:
    t0 = time.perf_counter()
    write_map(plan_map(refs, out, options))
    return time.perf_counter() - t0


def main(argv: Sequence[str] | None = None) -> int:
    p = parser(__name__, __doc__)
    p.add_argument("--refs", type=Path, required=True)
    p.add_argument("--ray", default="local")
    p.add_argument("--threads", type=int, default=0, help="the plain build's onnxruntime threads (0: a core each)")
    p.add_argument("--codebook-first", action="store_true")
    a = p.parse_args(argv)

    def run() -> int:
        import ray

        with tempfile.TemporaryDirectory() as tmp:
            folder = Path(tmp)
            codebook = None
            if a.codebook_first:
                codebook = folder / "cb.npz"
                write_map(plan_map(a.refs, folder / "fit.npz", BuildOptions(save_codebook=codebook)))
            plain_s = timed_build(a.refs, folder / "plain.npz", BuildOptions(threads=a.threads, codebook=codebook))
            ray_s = timed_build(a.refs, folder / "ray.npz", BuildOptions(codebook=codebook, ray=a.ray))
            cpus = int(ray.cluster_resources().get("CPU", 0))
            x, y = (load_map(folder / n).stored.to_arrays() for n in ("plain.npz", "ray.npz"))
            same = set(x) == set(y) and all(np.array_equal(x[k], y[k]) for k in x)
            n = len(load_map(folder / "plain.npz").names)
        print(f"{n} references{' (codebook given: every one through the per-frame work)' if codebook else ''}")
        print(f"plain build: {plain_s:.1f} s, {n / plain_s:.1f} frames/s")
        print(f"--ray {a.ray}: {ray_s:.1f} s, {n / ray_s:.1f} frames/s, {cpus} worker CPUs "
              f"({n / ray_s / max(cpus, 1):.1f} frames/s each, start-up included)")
        print(f"the same map byte for byte: {same}")
        return 0 if same else 1
    return run_checked(__name__, run)

