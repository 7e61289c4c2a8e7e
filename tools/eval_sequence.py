#!/usr/bin/env python3
"""Match accuracy on a real reference/query sequence pair, for every matching mode.

    python tools/eval_sequence.py                       # ../shared/datasets/corridor, else the bundled sample
    python tools/eval_sequence.py --dataset DIR --gt-margin 2 --tolerance 1

DIR holds ref/, query/ and ground_truth.csv (query,references). The true reference of a query is the centre
of its ground-truth window (+-gt-margin frames); a match counts as correct within --tolerance frames of it.
Also printed: the share of matches inside the dataset's own ground-truth set.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from vpr_edge.errors import VprError  # noqa: E402
from vpr_edge.evaluate import fraction_in_sets, fraction_within, load_ground_truth, window_centres  # noqa: E402
from vpr_edge.extract import FeatureExtractor, default_model_path  # noqa: E402
from vpr_edge.images import list_images, load_image  # noqa: E402
from vpr_edge.mapfile import build_map  # noqa: E402
from vpr_edge.match import StreamingDTW, best_match, dtw_align  # noqa: E402


def default_dataset() -> Path:
    shared = ROOT.parent / "shared" / "datasets" / "corridor"
    return shared if shared.is_dir() else ROOT / "samples" / "corridor"


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--dataset", type=Path, default=default_dataset())
    p.add_argument("--model", type=Path, default=None)
    p.add_argument("--components", type=int, default=128)
    p.add_argument("--pca-dim", type=int, default=None)
    p.add_argument("--alpha", type=float, default=0.5)
    p.add_argument("--decay", type=float, default=0.9)
    p.add_argument("--gt-margin", type=int, default=2, help="half-width of the ground-truth windows (Corridor: 2)")
    p.add_argument("--tolerance", type=int, default=1, help="frames of slack for a correct match (thesis: 1)")
    a = p.parse_args()
    try:
        ex = FeatureExtractor(a.model or default_model_path())
        t0 = time.perf_counter()
        pm = build_map(list_images(a.dataset / "ref"), ex, n_components=a.components, pca_dim=a.pca_dim, alpha=a.alpha)
        t1 = time.perf_counter()
        qfiles = list_images(a.dataset / "query")
        queries = np.concatenate([pm.encode(x[None]) for x in ex.iter_local_features(load_image(f) for f in qfiles)])
        t2 = time.perf_counter()
        truth_sets = load_ground_truth(a.dataset / "ground_truth.csv")
    except VprError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if len(truth_sets) != len(qfiles):
        print(f"error: ground truth has {len(truth_sets)} queries, folder has {len(qfiles)}", file=sys.stderr)
        return 2
    truth = window_centres(truth_sets, a.gt_margin, len(pm.names))
    sim = queries @ pm.encodings.T
    stream = StreamingDTW(len(pm.names), a.decay)
    preds = {
        "stream-dtw (distance, decay %.2f)" % a.decay: np.array([stream.update(row)[0] for row in sim]),
        "offline dtw (similarity, thesis)": dtw_align(sim, "similarity").matches,
        "offline dtw (distance)": dtw_align(sim, "distance").matches,
        "best single match": best_match(sim)[0],
    }
    print(f"dataset {a.dataset}: {len(pm.names)} refs, {len(qfiles)} queries; model {ex.info['backbone']}/"
          f"{ex.info['tap']} {ex.size[0]}x{ex.size[1]}; IFV M={pm.codebook.gmm.n_components} "
          f"K={pm.codebook.gmm.dim} alpha={a.alpha} ({pm.encodings.shape[1]} dims)")
    print(f"build-map {t1 - t0:.1f} s, query encoding {1e3 * (t2 - t1) / len(qfiles):.1f} ms/frame")
    print(f"{'mode':36s} {'within +-%d' % a.tolerance:>12s} {'in GT set':>10s}")
    for name, pred in preds.items():
        within, in_set = fraction_within(pred, truth, a.tolerance), fraction_in_sets(pred, truth_sets)
        print(f"{name:36s} {within:12.3f} {in_set:10.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
