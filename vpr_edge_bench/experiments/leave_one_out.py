"""Leave one dataset out, both ways: the stream-rules matcher's settings chosen on one, scored on the other.

Leave one dataset out, both ways: the stream-rules matcher's settings chosen on one dataset by written rules,
then scored on the other beside its own choice and the package defaults.

    python -m vpr_edge_bench leave-one-out --streams out/nordland-dev out/corridor [--tolerance 2]

Each folder is ``derive-streams`` output with its default map.npz. On each dataset the rules of
``RULES`` choose one parameter at a time, in that order, from ``evaluate`` (the function behind ``vpr-edge
evaluate``: the map's front end, the motion cue) on all its derived streams, each with the parameters before
it at the values chosen and the rest at the defaults (``still_memory`` is not chosen: 10 to 100 frames move
no dataset's mean R@1 by more than 0.003). Every dataset is then scored with the settings chosen
on the other (held out: nothing of it was seen), with its own, and with the package defaults: per stream the
share of answers given that are right and of mapped frames answered right (also over the frames whose truth
does not lie where the map shows one view, ``truth.one_view``), the detour's unmapped frames reported lost
and the frames from leaving the map to the first lost one, the mean R@1. Bad input is one line on stderr and
exit code 2, before any work.
"""
from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vpr_edge.evaluation.scoring import ModeReport
from vpr_edge.matchers import Matcher, get_matcher
from vpr_edge.matchers.params import STREAM_RULES
from vpr_edge_bench.folder import StreamsFolder, streams_folders
from vpr_edge_bench.runner import check_tolerance, parser, run_checked
from vpr_edge_bench.streams import KINDS

Table = dict[float, dict[str, ModeReport]]   # a parameter's value -> stream kind -> the stream-rules matcher's report


def _share(report: ModeReport, other: bool) -> float:
    """Mapped frames answered right, over all frames or over the frames away from one-view runs."""
    return report.distinct_mapped_right if other else report.mapped_right


def best_recall(table: Table) -> float:
    """The value with the best mean R@1 over the streams (the first of the values tried on a tie)."""
    return max(table, key=lambda v: (np.mean([r.recall[1] for r in table[v].values()]), -list(table).index(v)))


def within(table: Table, drop: float, other: bool = False) -> list[float]:
    """The values at which no stream's share of mapped frames answered right falls more than ``drop`` below
    its share at the first value tried (a stream with nothing to count is no objection)."""
    base = table[next(iter(table))]
    return [v for v, per in table.items()
            if all(not _share(r, other) - _share(base[k], other) < -drop for k, r in per.items())]


def highest_within(drop: float, other: bool = False) -> Callable[[Table], float]:
    """The rule: the highest value ``within`` ``drop``."""
    return lambda table: max(within(table, drop, other))


def most_lost_within(drop: float) -> Callable[[Table], float]:
    """The rule: of the values ``within`` ``drop``, the one that reports most of the detour's unmapped frames
    lost (the lowest on a tie)."""
    return lambda table: min(within(table, drop), key=lambda v: (-table[v]["detour"].lost_unmapped, v))


@dataclass(frozen=True)
class Rule:
    """How one ``stream-rules`` parameter is chosen on a dataset: ``choose`` over its reports at each of ``values``
    (the first is the one drops are measured from); ``says``: the rule in words."""

    param: str
    values: tuple[float, ...]
    says: str
    choose: Callable[[Table], float]


RULES: tuple[Rule, ...] = (
    Rule("still", (0.3, 0.4, 0.5, 0.6, 0.7), "best mean R@1", best_recall),
    Rule("lock", (5, 6, 6.5, 7, 7.5, 8), "highest with no stream's mapped right more than 0.02 below at 5",
         highest_within(0.02)),
    Rule("evidence", (-99, 1, 1.25, 1.5, 1.75, 2), "most of the detour's unmapped frames lost, no stream's "
         "mapped right more than 0.05 below at -99 (off)", most_lost_within(0.05)),
    Rule("unique", (0, 0.01, 0.02, 0.03, 0.04, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.4, 0.5), "highest with no "
         "stream's mapped right, away from one-view runs, more than 0.05 below at 0", highest_within(0.05, True)),
    Rule("confirm", (1, 2, 3, 4), "most of the detour's unmapped frames lost, no stream's mapped right more than "
         "0.02 below at 1 (off)", most_lost_within(0.02)),
)


def _stream(settings: dict[str, float]) -> Matcher:
    """The stream matcher with ``settings`` (whole-number parameters as whole numbers)."""
    return get_matcher("stream-rules").with_params(**{k: type(STREAM_RULES[k].default)(v) for k, v in settings.items()})


def _reports(folder: StreamsFolder, modes: dict[str, Matcher], tolerance: int) -> dict[str, dict[str, ModeReport]]:
    """Mode name -> stream kind -> report: ``evaluate`` on every derived stream of ``folder``."""
    per_kind = {kind: ev.reports for kind, ev in folder.evaluate(modes, tolerance)}
    return {name: {kind: per_kind[kind][name] for kind in KINDS} for name in modes}


def choose(folder: StreamsFolder, tolerance: int) -> dict[str, float]:
    """The settings ``RULES`` choose on the dataset of ``folder``, one parameter after another."""
    chosen: dict[str, float] = {}
    for rule in RULES:
        modes = {f"{v:g}": _stream(chosen | {rule.param: v}) for v in rule.values}
        got = _reports(folder, modes, tolerance)
        chosen[rule.param] = rule.choose({v: got[f"{v:g}"] for v in rule.values})
    return chosen


def main(argv: Sequence[str] | None = None) -> int:
    p = parser(__name__, __doc__)
    p.add_argument("--streams", type=Path, nargs=2, required=True,
                   help="two derived-streams folders (the dataset's name is the folder's), each with its map.npz")
    p.add_argument("--tolerance", type=int, default=2)
    a = p.parse_args(argv)
    return run_checked(__name__, lambda: _run(a))


def _run(a: argparse.Namespace) -> int:
    """The work of ``main``, inputs checked first."""
    check_tolerance(a.tolerance)
    folders = streams_folders(a.streams, distinct=True)
    names = [f.name for f in folders]
    chosen = {f.name: choose(f, a.tolerance) for f in folders}
    defaults = {r.param: float(STREAM_RULES[r.param].default) for r in RULES}
    print(f"stream-rules matcher, tolerance {a.tolerance}; each parameter chosen in this order, the ones above at the "
          "values chosen, the rest at the defaults\n")
    print(f"| parameter | values tried | rule | chosen on {names[0]} | chosen on {names[1]} | default |")
    print("|---|---|---|---|---|---|")
    for r in RULES:
        print(f"| `{r.param}` | {', '.join(f'{v:g}' for v in r.values)} | {r.says} | {chosen[names[0]][r.param]:g} | "
              f"{chosen[names[1]][r.param]:g} | {defaults[r.param]:g} |")
    print("\nscored on each dataset with the settings chosen on the other (held out), on its own, and the "
          "defaults; per stream: answers given right / mapped frames answered right\n")
    print(f"| scored on | settings | frames | {' | '.join(KINDS)} | detour unmapped lost (first) | mean R@1 |")
    print(f"|---|---|---|{'---|' * len(KINDS)}---|---|")
    for folder, other in zip(folders, reversed(folders)):
        settings = {f"chosen on {other.name} (held out)": chosen[other.name],
                    f"chosen on {folder.name} (own)": chosen[folder.name], "defaults": defaults}
        got = _reports(folder, {k: _stream(v) for k, v in settings.items()}, a.tolerance)
        for name, per in got.items():
            detour = per["detour"]
            first = "-" if not detour.exit_frames or np.isnan(detour.exit_frames[0]) else f"{detour.exit_frames[0]:.0f}"
            tail = f"{detour.lost_unmapped:.3f} ({first}) | {np.mean([r.recall[1] for r in per.values()]):.3f}"
            for label, ans, got_ in (("all", "answered_right", "mapped_right"),
                                     ("away from one view", "distinct_answered_right", "distinct_mapped_right")):
                cells = " | ".join(f"{getattr(per[k], ans):.3f} / {getattr(per[k], got_):.3f}" for k in KINDS)
                print(f"| {folder.name} | {name} | {label} | {cells} | {tail} |", flush=True)
    return 0

