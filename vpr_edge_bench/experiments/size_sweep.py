"""Accuracy against bytes per place: encodings of several sizes and storages on derived streams.

    python -m vpr_edge_bench derive-streams --dataset ../shared/datasets/nordland-dev --out out/nordland-dev
    python -m vpr_edge_bench size-sweep --streams out/nordland-dev --kinds aligned,speed2 --out out/size/nordland-dev

Local descriptors of the references (STREAMS/ref) and of each stream STREAMS/KIND are extracted once with the
default bundled model, 160x120 (or --model; cached in OUT/local/, re-extracted when the shape differs) and shared by every configuration. A configuration is an IFV codebook
(``--configs`` entries ``PCA_DIMxCOMPONENTS``, PCA 0 = none) fitted on the references by
``map_from_local`` (the function behind ``build-map``) and a storage (how the map keeps the references:
float32, int8 with a row scale, or sign bits). Each stream is scored by ``evaluate_mode`` (the function
behind ``vpr-edge evaluate``) with the single and stream matchers, each given the map's route and every
frame's motion cue from its encodings as ``evaluate`` gives them. Prints a Markdown table (also OUT/size.md,
OUT/size.json): dims, bytes per place, a 100,000-place map's size, fit seconds, then R@1 / AUC per stream
and mode.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vpr_edge.encoders import FitSettings
from vpr_edge.evaluation import truth as groundtruth
from vpr_edge.evaluation.scoring import evaluate_mode
from vpr_edge.features import make_front_end
from vpr_edge.frames.images import list_images
from vpr_edge.index.coarse import agreement, sign_bytes
from vpr_edge.index.encodings import Encodings, bytes_per_place
from vpr_edge.map import map_from_local
from vpr_edge.map.build import extract_all
from vpr_edge.matchers import get_matcher
from vpr_edge.resources import bundled_model
from vpr_edge.threads import use_threads
from vpr_edge_bench.folder import StreamsFolder
from vpr_edge_bench.runner import parser, run_checked
from vpr_edge_bench.streams import KINDS

BUNDLED_MODEL = bundled_model()


def cached_local(files: list[Path], front, folder: Path) -> np.ndarray:
    """Local descriptors (N, L, K) of ``files``, extracted once into ``folder``/local.npy (memory-mapped; used
    again only if it has the shape this front end gives those files)."""
    path = folder / "local.npy"
    if path.exists():
        arr = np.load(path, mmap_mode="r", allow_pickle=False)
        if arr.shape == (len(files), front.n_local, front.dim):
            return arr
    folder.mkdir(parents=True, exist_ok=True)
    local, _ = extract_all(files, front, folder, 8)
    local.flush()
    return np.load(path, mmap_mode="r", allow_pickle=False)


def stored_similarity(refs: np.ndarray, queries: np.ndarray, storage: str) -> np.ndarray:
    """Cosine-like similarities (Q, R) of float queries against references kept as ``storage`` ("bits":
    the coarse search's sign agreement, ``index.coarse.agreement``)."""
    if storage == "bits":
        return agreement(refs, queries).astype(np.float64)
    return Encodings.pack(refs, storage).similarity(queries).astype(np.float64)


def place_bytes(dim: int, storage: str) -> int:
    """Bytes a place: ``index.encodings.bytes_per_place``, or the packed signs for "bits"."""
    return sign_bytes(dim) if storage == "bits" else bytes_per_place(dim, storage)


def main(argv: Sequence[str] | None = None) -> int:
    p = parser(__name__, __doc__)
    p.add_argument("--streams", type=Path, required=True, help="a derived-streams folder: ref/ and KIND/ + KIND.csv")
    p.add_argument("--kinds", default="aligned,speed2", help="streams, comma-separated, or all")
    p.add_argument("--encoding", default="ifv", help="ifv, fv or vlad (PCAxCOMPONENTS as for ifv)")
    p.add_argument("--tolerance", type=int, default=1, help="frames either side counted right (evaluate's)")
    p.add_argument("--alpha", type=float, default=FitSettings.alpha, help="signed power normalisation (ifv, vlad)")
    p.add_argument("--no-whiten", action="store_true", help="PCA without whitening")
    p.add_argument("--configs", default="0x128,64x128,32x128,64x64,32x64,32x32,16x64,24x32")
    p.add_argument("--fits", default=f"{FitSettings.max_descriptors}x{FitSettings.iterations}",
                   help="codebook fits DESCRIPTORSxITERATIONS, comma-separated (default build-map's)")
    p.add_argument("--storages", default="int8,bits")
    p.add_argument("--seeds", default="0")
    p.add_argument("--modes", default="single,stream")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--model", type=Path, default=BUNDLED_MODEL, help="ONNX tap (default: the bundled one)")
    p.add_argument("--query-model", type=Path, default=None,
                   help="describe the streams with this model instead (an int8 form of --model: a map built "
                        "with --model, queried with it)")
    p.add_argument("--threads", type=int, default=0)
    a = p.parse_args(argv)
    return run_checked(__name__, lambda: _run(a))


def _run(a: argparse.Namespace) -> int:
    """The work of ``main``, the folder checked first."""
    kinds = list(KINDS) if a.kinds == "all" else a.kinds.split(",")
    folder = StreamsFolder(a.streams, kinds).check(map=False, ref=True)
    use_threads(a.threads)
    a.out.mkdir(parents=True, exist_ok=True)
    front = make_front_end("cnn", a.model, a.threads)
    modes = a.modes.split(",")
    t0 = time.perf_counter()
    refs = list_images(folder.ref)
    ref_local = cached_local(refs, front, a.out / "local" / "ref")
    q_front, q_dir = front, "local"
    if a.query_model is not None:
        q_front, q_dir = make_front_end("cnn", a.query_model, a.threads), f"local-{a.query_model.stem}"
    queries = {k: (cached_local(list_images(folder.frames(k)), q_front, a.out / q_dir / k),
                   groundtruth.load_csv(folder.truth(k))) for k in kinds}
    print(f"local descriptors: {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    rows = []
    for config, fit in ((c, f) for c in a.configs.split(",") for f in a.fits.split(",")):
        pca, comps = (int(v) for v in config.split("x"))
        n_desc, iters = (int(v) for v in fit.split("x"))
        for seed in (int(s) for s in a.seeds.split(",")):
            t1 = time.perf_counter()
            settings = FitSettings(n_components=comps, pca_dim=pca or None, seed=seed, max_descriptors=n_desc,
                                   iterations=iters, alpha=a.alpha, whiten=not a.no_whiten)
            pm = map_from_local(ref_local, None, front, [f.name for f in refs], "ref", a.encoding,
                                settings=settings)
            fit_s = time.perf_counter() - t1
            ref_enc = pm.stored.dense()
            q_enc = {k: pm.encoder.transform_chunked(v[0]) for k, v in queries.items()}
            for storage in a.storages.split(","):
                row = {"encoding": a.encoding, "alpha": a.alpha, "whiten": not a.no_whiten, "pca": pca, "components": comps, "fit": fit, "seed": seed, "storage": storage,
                       "dim": pm.encoder.dim,
                       "bytes": place_bytes(pm.encoder.dim, storage), "fit_s": round(fit_s, 1)}
                matchers = {m: get_matcher(m).on_route(pm.stored.in_order()) for m in modes}   # as evaluate runs them
                for k, (_, truth) in queries.items():
                    sim = stored_similarity(ref_enc, q_enc[k], storage)
                    for mode, matcher in matchers.items():
                        r = evaluate_mode(matcher, sim, truth, a.tolerance, still=matcher.cue(q_enc[k]))
                        row[f"{k} {mode}"] = (round(r.recall[1], 3), round(r.auc, 3))
                rows.append(row)
                print(json.dumps(row), file=sys.stderr, flush=True)
    cols = [f"{k} {m}" for k in kinds for m in modes]
    lines = [f"R@1 / AUC on {a.streams} ({len(refs)} references), {a.encoding}, tolerance {a.tolerance}; "
             f"{(time.perf_counter() - t0) / 60:.1f} min", "",
             "| PCA | components | fit | seed | storage | dims | bytes/place | 100,000 places | fit s | "
             + " | ".join(cols) + " |",
             "|---" * (9 + len(cols)) + "|"]
    for r in rows:
        lines.append(f"| {r['pca'] or 'none'} | {r['components']} | {r['fit']} | {r['seed']} | {r['storage']} | "
                     f"{r['dim']:,} | "
                     f"{r['bytes']:,} | {r['bytes'] * 100_000 / 1e6:,.0f} MB | {r['fit_s']} | "
                     + " | ".join(f"{r[c][0]:.3f} / {r[c][1]:.3f}" for c in cols) + " |")
    lines += ["", "Means over the seeds and streams, per mode:", "",
              "| PCA | components | storage | bytes/place | " + " | ".join(f"{m} R@1 / AUC" for m in modes) + " |",
              "|---" * (4 + len(modes)) + "|"]
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault((r["pca"], r["components"], r["storage"]), []).append(r)
    for (pca, comps, storage), rs in groups.items():
        means = []
        for m in modes:
            cells = [r[f"{k} {m}"] for r in rs for k in kinds]
            means.append(f"{np.mean([c[0] for c in cells]):.3f} / {np.mean([c[1] for c in cells]):.3f}")
        lines.append(f"| {pca or 'none'} | {comps} | {storage} | {rs[0]['bytes']:,} | " + " | ".join(means) + " |")
    (a.out / "size.md").write_text("\n".join(lines) + "\n")
    (a.out / "size.json").write_text(json.dumps(rows, indent=1) + "\n")
    print("\n".join(lines))
    return 0

