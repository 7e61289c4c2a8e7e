#!/usr/bin/env python3
"""The results tables (docs/results.md, "Evaluating"): `vpr-edge evaluate` on every derived stream of a dataset, CNN map and pixels.

    python tools/derive_streams.py --dataset ../shared/datasets/corridor --out out/corridor
    vpr-edge build-map out/corridor/ref --out out/corridor/map.npz
    python tools/eval_streams.py --streams out/corridor --modes single,stream,dtw,dtw-open,seqslam,seqslam-online

For each stream OUT/KIND (with OUT/KIND.csv) it runs `vpr-edge evaluate --map OUT/map.npz` and
`vpr-edge evaluate --features pixels --refs OUT/ref`, each writing OUT/eval/KIND.{map,pixels}.json, then prints
Markdown tables of R@1 and AUC (rows: front end + mode; columns: streams) and the stream mode's lost shares
and lock-on / exit frames on the detour.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path


from vpr_edge.evaluation.report import delays_text
from vpr_edge.evaluation.streams import KINDS


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--streams", type=Path, required=True)
    p.add_argument("--modes", default="single,stream,stream-dtw,dtw,dtw-open,seqslam,seqslam-online")
    p.add_argument("--tolerance", default="1")
    p.add_argument("--plot", default="aligned", help="stream whose PR curves go to OUT/eval/KIND.pr.png")
    a = p.parse_args()
    out = a.streams / "eval"
    out.mkdir(exist_ok=True)
    results: dict[tuple[str, str], dict] = {}
    for kind in KINDS:
        for front, source in (("map", ["--map", str(a.streams / "map.npz")]),
                              ("pixels", ["--features", "pixels", "--refs", str(a.streams / "ref")])):
            js = out / f"{kind}.{front}.json"
            cmd = ["vpr-edge", "evaluate", *source, "--queries", str(a.streams / kind), "--gt",
                   str(a.streams / f"{kind}.csv"), "--modes", a.modes, "--tolerance", a.tolerance, "--json", str(js)]
            if kind == a.plot:
                cmd += ["--plot", str(out / f"{kind}.{front}.pr.png")]
            proc = subprocess.run(cmd, capture_output=True, text=True)
            if proc.returncode:
                print(proc.stderr, file=sys.stderr)
                return proc.returncode
            (out / f"{kind}.{front}.txt").write_text(proc.stdout)
            results[kind, front] = json.loads(js.read_text())
    for metric, key in (("R@1", "recall_at_1"), ("AUC", "auc")):
        print(f"\n{metric} ({a.streams}, tolerance {a.tolerance})\n")
        print("| front end / mode | " + " | ".join(KINDS) + " |")
        print("|---|" + "---|" * len(KINDS))
        for front in ("map", "pixels"):
            for mode in a.modes.split(","):
                vals = [results[k, front]["modes"][mode][key] for k in KINDS]
                print(f"| {'IFV' if front == 'map' else 'pixels'} {mode} | " +
                      " | ".join("-" if v is None else f"{v:.3f}" for v in vals) + " |")
    print("\nstream mode, detour stream: share of frames reported lost (unmapped places / mapped places); frames "
          "to lock on (start / re-entry) and to report lost after leaving the map:")
    for front in ("map", "pixels"):
        r = results["detour", front]["modes"].get("stream")
        if r is not None:
            print(f"  {front}: lost {r['lost_unmapped']:.3f} / {r['lost_mapped']:.3f}; lock "
                  f"{delays_text(r['lock_frames'])}; exit {delays_text(r['exit_frames'])}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
