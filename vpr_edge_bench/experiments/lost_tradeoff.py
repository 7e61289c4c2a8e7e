"""What the stream-rules matcher's lost threshold trades: off-map frames lost against mapped frames right.

What the stream-rules matcher's lost threshold trades: off-map frames reported lost against mapped frames
answered right, on every derived stream of each dataset.

    python -m vpr_edge_bench lost-tradeoff --streams out/corridor out/nordland-dev [--locks 5,6,6.5,7,8] [--tolerance 2]
        [--param decay=0.85 ...]

For each folder (``derive-streams`` output with its map.npz) every stream is evaluated once
(``evaluate``, the function behind ``vpr-edge evaluate``: the map's front end, the motion cue) with the
``stream-rules`` matcher at each ``lock`` (``--param lock=L``; or each value of the parameter ``--vary`` names, e.g.
``--vary evidence --values 0,1,1.5``; everything else default, or as ``--param`` sets it for every row) and prints, per lock: the detour's unmapped frames reported lost, frames from leaving the map
to the first lost frame and from re-entering to the first right answer; the lowest share of answered frames
right and of mapped frames answered right over the streams (and which stream); the largest drop of a
stream's mapped frames answered right from the default ``lock`` (always run, with the same ``--param``
values; or from ``--against``'s value); the same two over the frames whose truth does not lie where the map
shows one view (``truth.one_view``: a run of references its drive saw alike, where a frame-counted truth is a
count no image recovers); the mean ``stream-rules`` R@1 and AUC. Only which answers are called lost moves with ``lock`` (the
trajectory search is the same), so the table is the trade-off the threshold allows. Bad input (a lock that is
not a positive number, an unknown parameter, a folder without its map or streams) is one line on stderr and
exit code 2, before any work.
"""
from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vpr_edge.errors import VprError
from vpr_edge.matchers import get_matcher
from vpr_edge.matchers.params import STREAM_RULES
from vpr_edge_bench.folder import streams_folders
from vpr_edge_bench.runner import parser, run_checked
from vpr_edge_bench.streams import KINDS


def _frames(v: tuple[float, ...]) -> str:
    """Delays per run -> '6' / '6, 2' ('never' where it did not happen in the run)."""
    return ", ".join("never" if np.isnan(x) else f"{x:.0f}" for x in v) or "-"


def _or_inf(v: float) -> float:
    """A share for ``min``: NaN (nothing to count) ranks last."""
    return float("inf") if np.isnan(v) else v


def main(argv: Sequence[str] | None = None) -> int:
    p = parser(__name__, __doc__)
    p.add_argument("--streams", type=Path, nargs="+", required=True, help="derived-streams folders with map.npz")
    p.add_argument("--locks", "--values", dest="locks", default="5,6,6.5,7,8",
                   help="values of the varied parameter to compare (default: lost thresholds around lock's 6)")
    p.add_argument("--vary", default="lock", help="the stream-rules parameter the rows vary (default lock; e.g. evidence)")
    p.add_argument("--tolerance", type=int, default=2)
    p.add_argument("--param", action="append", default=[], metavar="KEY=VALUE",
                   help="another stream-rules parameter for every row (as `vpr-edge evaluate --param`)")
    p.add_argument("--against", type=float, default=None,
                   help="the value the drops are measured from (default: the parameter's default; e.g. 0 for a "
                        "rule read against the parameter switched off)")
    a = p.parse_args(argv)
    return run_checked(__name__, lambda: _run(a))


def _locks(text: str, vary: str = "lock") -> list[float]:
    """``--locks`` "5,6.5" -> [5.0, 6.5] (VprError unless each is a number, and for ``lock`` positive)."""
    try:
        locks = [float(x) for x in text.split(",")]
    except ValueError:
        locks = []
    if not locks or not all(np.isfinite(x) and (x > 0 or vary != "lock") for x in locks):
        raise VprError(f"--locks {text!r}: want {'positive ' if vary == 'lock' else ''}numbers separated by "
                       "commas, e.g. 5,6.5,7")
    return locks


def _run(a: argparse.Namespace) -> int:
    """The work of ``main``, inputs checked first: --locks, --param, each folder's map and streams."""
    numeric = [k for k, p in STREAM_RULES.items() if isinstance(p.default, (int, float)) and not isinstance(p.default, bool)]
    if a.vary not in numeric:
        raise VprError(f"--vary {a.vary!r}: not a numeric stream parameter ({', '.join(numeric)})")
    locks = _locks(a.locks, a.vary)
    kind = type(STREAM_RULES[a.vary].default)   # an int parameter (e.g. still_memory) takes whole values
    if kind is int and any(x != int(x) for x in locks):
        raise VprError(f"--values: {a.vary} takes whole numbers")
    default = float(STREAM_RULES[a.vary].default if a.against is None else a.against)
    if not np.isfinite(default) or (kind is int and default != int(default)):
        raise VprError(f"--against {a.against:g}: want a {'whole ' if kind is int else ''}number")
    try:
        fixed = get_matcher("stream-rules").parse_params(a.param)
        for x in [*locks, default]:   # one at a time: the items of one call set one key
            get_matcher("stream-rules").parse_params([f"{a.vary}={kind(x)}"])
    except ValueError as e:
        raise VprError(str(e)) from None
    folders = streams_folders(a.streams)
    locks = sorted(set(locks) | {default})
    modes = {f"{a.vary}={x:g}": get_matcher("stream-rules").with_params(**fixed | {a.vary: kind(x)}) for x in locks}
    print(f"stream-rules matcher{''.join(f' {k}={v}' for k, v in fixed.items())}, tolerance {a.tolerance}; "
          "worst stream in brackets\n")
    print(f"| dataset | `{a.vary}` | detour unmapped lost | exit frames | re-lock frames | min answered right "
          f"| min mapped right | mapped right, largest drop from {default:g} | other frames: min answered right | "
          f"other frames: mapped right, largest drop from {default:g} | mean R@1 / AUC |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for folder in folders:
        reports = {kind: ev.reports for kind, ev in folder.evaluate(modes, a.tolerance)}
        for name in modes:
            per = {kind: r[name] for kind, r in reports.items()}
            detour = per["detour"]
            ans = min(KINDS, key=lambda k: _or_inf(per[k].answered_right))   # NaN: nothing answered
            got = min(KINDS, key=lambda k: _or_inf(per[k].mapped_right))
            drop = {k: per[k].mapped_right - reports[k][f"{a.vary}={default:g}"].mapped_right for k in KINDS}
            worst = min(KINDS, key=drop.get)
            # over the frames whose truth does not lie where the map shows one view (``truth.one_view``)
            ans_o = min(KINDS, key=lambda k: _or_inf(per[k].distinct_answered_right))
            drop_o = {k: per[k].distinct_mapped_right - reports[k][f"{a.vary}={default:g}"].distinct_mapped_right
                      for k in KINDS}
            worst_o = min(KINDS, key=lambda k: _or_inf(drop_o[k]))
            print(f"| {folder.name} | {name.split('=')[1]} | {detour.lost_unmapped:.3f} | "
                  f"{_frames(detour.exit_frames)} | {_frames(detour.lock_frames[1:])} | "
                  f"{per[ans].answered_right:.3f} ({ans}) | {per[got].mapped_right:.3f} ({got}) | "
                  f"{drop[worst]:+.3f} ({worst}) | {per[ans_o].distinct_answered_right:.3f} ({ans_o}) | "
                  f"{drop_o[worst_o]:+.3f} ({worst_o}) | {np.mean([per[k].recall[1] for k in KINDS]):.3f} / "
                  f"{np.mean([per[k].auc for k in KINDS]):.3f} |", flush=True)
    return 0

