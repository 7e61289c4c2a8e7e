"""The thesis's experiment grid on one dataset pair: front ends x encodings x matchers, a Markdown table and
PR curves.

    python -m vpr_edge_bench derive-streams --dataset ../shared/datasets/corridor --out out/grid-streams/corridor \
        --kinds speed2 --map-places 111
    python -m vpr_edge_bench thesis-grid --dataset ../shared/datasets/corridor \
        --stream out/grid-streams/corridor/speed2 --out out/grid/corridor

Groups (as the thesis's chapters): (1) handcrafted front ends (HOG, SIFT dense, SIFT on keypoints, LDB,
SeqSLAM's pixels), single frames vs DTW; (2) each tap of the bundled network (EfficientNet-Lite0 stage3 ...
head, exported with the export extra into --models; plus any --model given, e.g. VGG16/ResNet50/HybridNet
taps exported from their weights) with IFV, single vs DTW; (3) the five encodings on the best tap of (2)
(by DTW AUC on the derived stream, as fixed-end DTW is perfect on any aligned pair), each with single,
DTW and SVM: encoded vs not, DTW vs SVM.

Query sets: the aligned pair (query i is place i; the thesis's 1-frame tolerance) and, with --stream, a
derived stream (derive-streams with --map-places = all references, so that the stream runs the
whole route and fixed-end DTW's ends are right: its frames and KIND.csv, place indices into the same
references).
Every figure comes from ``vpr_edge.evaluation.evaluate_mode``, the function behind ``vpr-edge evaluate``;
maps are made by ``vpr_edge.map.map_from_local``, the map building behind ``vpr-edge build-map`` (local
features are extracted once per front end and reused across encodings). Writes OUT/grid.md, OUT/grid.json
and OUT/<group>.<queries>.pr.png.
"""
from __future__ import annotations

import json
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vpr_edge.encoders import ENCODERS, FitSettings
from vpr_edge.evaluation import report
from vpr_edge.evaluation import truth as groundtruth
from vpr_edge.evaluation.scoring import ModeReport, evaluate_mode
from vpr_edge.features import make_front_end
from vpr_edge.frames.images import list_images
from vpr_edge.map import map_from_local
from vpr_edge.map.build import extract_all
from vpr_edge.matchers import get_matcher
from vpr_edge.resources import bundled_model
from vpr_edge.threads import use_threads
from vpr_edge_bench.runner import parser

ROOT = Path(__file__).resolve().parents[2]   # the checkout: exported taps go to its out/models by default
BUNDLED_MODEL = bundled_model()
HANDCRAFTED = [("hog", "none"), ("sift", "none"), ("sift-kp", "ifv"), ("ldb", "none"), ("pixels", "none")]
LITE0_TAPS = ("stage3", "stage4", "stage5", "stage6", "stage7", "head")
THESIS = {"VGG16 block4_conv3 + IFV + DTW, GardensPoint day (thesis)": 0.899,
          "ResNet50 res4f + IFV + DTW, berlin_A100 (thesis)": 0.699}


def lite0_taps(models: Path) -> list[Path]:
    """ONNX files of every EfficientNet-Lite0 tap at 320x240 (the bundled one for stage5; the others exported
    into ``models`` once, if the export extra is installed)."""
    out = []
    for tap in LITE0_TAPS:
        path = BUNDLED_MODEL if tap == "stage5" else models / f"efficientnet_lite0_{tap}_320x240.onnx"
        if not path.exists():
            try:
                from vpr_edge_export.onnx_export import default_weights, export_onnx
            except ImportError:
                print(f"skipping tap {tap}: the export extra (torch) is not installed", file=sys.stderr)
                continue
            export_onnx("efficientnet_lite0", tap, default_weights("efficientnet_lite0"), 320, 240, path)
        out.append(path)
    return out


class Grid:
    """Runs configurations, caching local features per front end and image set."""

    def __init__(self, refs: list[Path], queries: dict[str, tuple[list[Path], np.ndarray]], tmp: Path,
                 settings: FitSettings) -> None:
        self.refs, self.queries, self.tmp, self.settings = refs, queries, tmp, settings
        self.rows: list[dict] = []
        self.reports: dict[tuple[str, str, str, str], ModeReport] = {}
        self._cache: dict[tuple[str, Path | None], tuple] = {}

    def local(self, front_name: str, model: Path | None) -> tuple:
        """(front end, (ref local, ref mask), {query set: (local, mask)}), extracted once per front end."""
        key = (front_name, model)
        if key not in self._cache:
            front = make_front_end(front_name, model, 0)
            folder = Path(tempfile.mkdtemp(dir=self.tmp))
            sets = {}
            for name, files in [("refs", self.refs)] + [(q, v[0]) for q, v in self.queries.items()]:
                (folder / name).mkdir()
                sets[name] = extract_all(files, front, folder / name, 8)
            refs = sets.pop("refs")
            self._cache[key] = (front, refs, sets)
        return self._cache[key]

    def run(self, group: str, label: str, front_name: str, model: Path | None, encodings: list[str],
            modes: list[str]) -> None:
        t0 = time.perf_counter()
        front, (ref_local, ref_mask), q_local = self.local(front_name, model)
        t_extract = time.perf_counter() - t0
        for encoding in encodings:
            t1 = time.perf_counter()
            pm = map_from_local(ref_local, ref_mask, front, [f.name for f in self.refs], "refs", encoding,
                                settings=self.settings, svm="svm" in modes)
            refit = getattr(front, "needs_fit", False)   # fitted on the references (LDB's bits): as the map says
            fitted = make_front_end(front_name, model, 0, spec=pm.features) if refit else front
            for qname, (local, mask) in q_local.items():
                if refit:
                    local = fitted.select(local)
                enc = pm.encoder.transform_chunked(local, mask)
                sims = {"cosine": pm.scores(enc, "cosine").astype(np.float64)}
                if "svm" in modes:
                    sims["svm"] = pm.scores(enc, "svm").astype(np.float64)
                truth = self.queries[qname][1]
                for mode in modes:
                    m = get_matcher(mode)
                    r = evaluate_mode(m, sims[m.scores], truth, tolerance=1)
                    self.reports[group, f"{label} + {encoding}", mode, qname] = r
                    self.rows.append({"group": group, "config": f"{label} + {encoding}", "front_end": front_name,
                                      "model": model.name if model else None, "encoding": encoding, "mode": mode,
                                      "queries": qname, "dim": int(pm.stored.shape[1])} | r.as_json())
            print(f"  {label} + {encoding}: {pm.stored.shape[1]} dims, extract {t_extract:.0f} s (once), "
                  f"fit+encode+match {time.perf_counter() - t1:.0f} s", file=sys.stderr, flush=True)

    def table(self, group: str) -> str:
        qnames = list(self.queries)
        head = "| configuration | mode | " + " | ".join(f"{q} AUC | {q} AP | {q} R@1" for q in qnames) + " |"
        lines = [head, "|---|---|" + "---|" * (3 * len(qnames))]
        keys = [(c, m) for (g, c, m, q) in self.reports if g == group and q == qnames[0]]
        for config, mode in keys:
            cells = []
            for q in qnames:
                r = self.reports[group, config, mode, q]
                cells += [f"{r.auc:.3f}", f"{r.ap:.3f}", f"{r.recall[1]:.3f}"]
            lines.append(f"| {config} | {mode} | " + " | ".join(cells) + " |")
        return "\n".join(lines)

    def plots(self, out: Path, group: str) -> None:
        for q in self.queries:
            chosen = {f"{c} {m}": r for (g, c, m, qq), r in self.reports.items() if g == group and qq == q}
            report.plot(out / f"{group}.{q}.pr.png", chosen, f"{group}, {q} ({len(self.queries[q][0])} queries)")


def main(argv: Sequence[str] | None = None) -> int:
    p = parser(__name__, __doc__)
    p.add_argument("--dataset", type=Path, required=True, help="folder with ref/ and query/ aligned frame by frame")
    p.add_argument("--stream", type=Path, default=None, help="a derived stream folder (its .csv beside it)")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--models", type=Path, default=ROOT / "out" / "models", help="where exported taps are kept")
    p.add_argument("--model", type=Path, action="append", default=[], help="another ONNX tap for group 2")
    p.add_argument("--components", type=int, default=128, help="codebook size (thesis: 128)")
    p.add_argument("--threads", type=int, default=0)
    p.add_argument("--groups", default="handcrafted,taps,encodings")
    a = p.parse_args(argv)
    use_threads(a.threads)
    a.out.mkdir(parents=True, exist_ok=True)
    a.models.mkdir(parents=True, exist_ok=True)
    refs, aligned = list_images(a.dataset / "ref"), list_images(a.dataset / "query")
    queries = {"aligned": (aligned, groundtruth.pad([[i] for i in range(len(aligned))]))}
    if a.stream is not None:
        queries[a.stream.name] = (list_images(a.stream), groundtruth.load_csv(a.stream.with_suffix(".csv")))
    groups = a.groups.split(",")
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="vpr-grid-") as tmp:
        grid = Grid(refs, queries, Path(tmp), FitSettings(n_components=a.components, pca_dim=None))
        if "handcrafted" in groups:
            for front, encoding in HANDCRAFTED:
                grid.run("handcrafted", front, front, None, [encoding], ["single", "dtw"])
        best = BUNDLED_MODEL
        if "taps" in groups:
            taps = lite0_taps(a.models) + a.model
            for model in taps:
                grid.run("taps", model.stem, "cnn", model, ["ifv"], ["single", "dtw"])
            judge = list(queries)[-1]    # the derived stream if given (every tap's DTW is ~1 on the aligned pair)
            scored = [(grid.reports["taps", f"{m.stem} + ifv", "dtw", judge].auc,
                       grid.reports["taps", f"{m.stem} + ifv", "single", judge].auc, str(m)) for m in taps]
            best = Path(max(scored)[2])
        if "encodings" in groups:
            grid.run("encodings", best.stem, "cnn", best, list(ENCODERS), ["single", "dtw", "svm"])
    minutes = (time.perf_counter() - t0) / 60
    doc = [f"# Thesis grid: {a.dataset.name}", "",
           f"{len(refs)} references; query sets: " + ", ".join(f"{q} ({len(v[0])} frames)" for q, v in queries.items())
           + f"; correct within 1 frame; codebooks of {a.components}; {minutes:.1f} min.", ""]
    for g in groups:
        doc += [f"## {g}", "", grid.table(g), ""]
        grid.plots(a.out, g)
    doc += ["Thesis figures for reference (other datasets): " + "; ".join(f"{k}: AUC {v}" for k, v in THESIS.items())]
    (a.out / "grid.md").write_text("\n".join(doc) + "\n")
    (a.out / "grid.json").write_text(json.dumps(grid.rows, indent=1) + "\n")
    print("\n".join(doc))
    return 0

