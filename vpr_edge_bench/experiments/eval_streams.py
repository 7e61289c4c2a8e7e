"""Every mode on every derived stream of a dataset, the map's front end and SeqSLAM's pixels: Markdown tables.

    python -m vpr_edge_bench derive-streams --dataset ../shared/datasets/corridor --out out/corridor
    vpr-edge build-map out/corridor/ref --out out/corridor/map.npz
    python -m vpr_edge_bench eval-streams --streams out/corridor --modes single,stream,dtw,seqslam,seqslam-online
    python -m vpr_edge_bench eval-streams --streams out/corridor --modes single,stream --tolerance 2 \
        --fronts map --standardise

For each stream STREAMS/KIND (with STREAMS/KIND.csv) it runs ``evaluate`` (the function behind ``vpr-edge
evaluate``) with the map STREAMS/map.npz and with SeqSLAM's pixel front end against STREAMS/ref, each writing
what ``vpr-edge evaluate`` prints and its ``--json`` to STREAMS/eval/KIND.{map,pixels}.{txt,json} (``--plot``'s
stream also its PR curves, KIND.{map,pixels}.pr.png: the plot extra), then prints Markdown tables of R@1 and AUC
(rows: front end + mode; columns: streams), of mapped frames answered right and of answers right, and the
stream mode's lost shares and lock-on / exit frames on the
detour. ``--standardise``: the map's cosines standardised (``vpr-edge evaluate --standardise``); ``--fronts``:
``map``, ``pixels`` or both. Bad input (a folder without its map or streams, an unknown mode) is one line on stderr and exit code 2,
before any work.
"""
from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from vpr_edge.encoders.standardise import STANDARDISE
from vpr_edge.errors import VprError
from vpr_edge.evaluation import report
from vpr_edge.matchers import MATCHERS, get_matcher
from vpr_edge_bench.folder import StreamsFolder
from vpr_edge_bench.runner import check_tolerance, parser, run_checked

FRONTS = ("map", "pixels")   # the folder's map.npz; SeqSLAM's pixels against its ref/


def main(argv: Sequence[str] | None = None) -> int:
    p = parser(__name__, __doc__)
    p.add_argument("--streams", type=Path, required=True, help="a derived-streams folder with its map.npz")
    p.add_argument("--modes", default="single,stream,stream-dtw,dtw,dtw-open,seqslam,seqslam-online")
    p.add_argument("--tolerance", type=int, default=1)
    p.add_argument("--plot", default="aligned", help="stream whose PR curves go to STREAMS/eval/KIND.FRONT.pr.png "
                                                     "(empty: none)")
    p.add_argument("--fronts", default=",".join(FRONTS), help="map, pixels or both (comma-separated)")
    p.add_argument("--standardise", action=argparse.BooleanOptionalAction, default=STANDARDISE,
                   help="the map's cosines standardised (evaluate --standardise; --no-standardise: raw cosines)")
    a = p.parse_args(argv)
    return run_checked(__name__, lambda: _run(a))


def _run(a: argparse.Namespace) -> int:
    """The work of ``main``, inputs checked first."""
    modes = [m for m in a.modes.split(",") if m]
    unknown = [m for m in modes if m not in MATCHERS]
    if unknown or not modes:
        raise VprError(f"--modes {a.modes!r}: unknown {', '.join(unknown) or '(none)'}; choose from "
                       f"{', '.join(MATCHERS)}")
    check_tolerance(a.tolerance)
    fronts = [f for f in a.fronts.split(",") if f]
    if not fronts or any(f not in FRONTS for f in fronts):
        raise VprError(f"--fronts {a.fronts!r}: choose from {', '.join(FRONTS)}")
    folder = StreamsFolder(a.streams).check(map=True, ref=True)
    if a.plot:
        report.require_matplotlib()
    matchers = {m: get_matcher(m) for m in modes}
    out = folder.path / "eval"
    out.mkdir(exist_ok=True)
    results: dict[tuple[str, str], dict] = {}
    for front in fronts:
        for kind, ev in folder.evaluate(matchers, a.tolerance, pixels=front == "pixels",
                                        standardise=a.standardise and front == "map"):
            q, r = ev.similarity.shape
            (out / f"{kind}.{front}.txt").write_text(report.table(ev.reports, details=True) + "\n")
            report.write_json(out / f"{kind}.{front}.json", q, r, ev.reports, a.tolerance, ev.front)
            if kind == a.plot:
                title = report.figure_title(ev.similarity.shape, map_path=folder.map if front == "map" else None,
                                            refs=folder.ref if front == "pixels" else None,
                                            queries=folder.frames(kind))
                report.plot(out / f"{kind}.{front}.pr.png", ev.reports, title)
            results[kind, front] = {m: rep.as_json() for m, rep in ev.reports.items()}
    kinds = folder.kinds
    for metric, key in (("R@1", "recall_at_1"), ("AUC", "auc"), ("mapped right", "mapped_right"),
                        ("answered right", "answered_right")):
        print(f"\n{metric} ({a.streams}, tolerance {a.tolerance})\n")
        print("| front end / mode | " + " | ".join(kinds) + " |")
        print("|---|" + "---|" * len(kinds))
        for front in fronts:
            for mode in modes:
                vals = [results[k, front][mode][key] for k in kinds]
                print(f"| {'IFV' if front == 'map' else 'pixels'} {mode} | " +
                      " | ".join("-" if v is None else f"{v:.3f}" for v in vals) + " |")
    print("\nstream mode, detour stream: share of frames reported lost (unmapped places / mapped places); frames "
          "to lock on (start / re-entry) and to report lost after leaving the map:")
    for front in fronts:
        r = results["detour", front].get("stream")
        if r is not None:
            print(f"  {front}: lost {r['lost_unmapped']:.3f} / {r['lost_mapped']:.3f}; lock "
                  f"{report.delays_text(r['lock_frames'])}; exit {report.delays_text(r['exit_frames'])}")
    return 0
