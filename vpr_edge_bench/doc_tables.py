"""The tables the ``results`` experiment writes into the README and docs/results.md, from the figures it measured
(docs/generated/results.json): ``readme_table`` and ``answers_table``, each between its markers
(``TABLE_START`` ... ``TABLE_END``) in its document; ``replace_between`` puts a body between two markers."""
from __future__ import annotations

from pathlib import Path

from vpr_edge.errors import VprError

TABLE_START = "<!-- results table: python -m vpr_edge_bench results -->\n"
TABLE_END = "<!-- end of results table -->"

STREAM_LABELS = {"aligned": "aligned", "speed2": "speed ×2", "speed3": "speed ×3", "stop-and-go": "stop-and-go",
                 "camera-stops": "camera stops", "variable": "variable speed", "partial": "partial route",
                 "detour": "detour"}


def _dataset_label(name: str) -> str:
    """How the tables name a shared dataset (Corridor is a proper name; nordland-dev a folder's)."""
    return name.capitalize() if name == "corridor" else name


def answers_table(doc: dict) -> str:
    """docs/results.md's "Right or silent" table from the ``results`` experiment's JSON: per dataset, the share of
    answered frames right and of mapped frames answered right by the ``stream`` matcher within ±2; then the
    mapped frames whose truth lies where the map shows one view (``truth.one_view``) and the two shares over
    the other frames ('-' where the JSON has none)."""
    names = list(doc["datasets"])
    kinds = list(doc["datasets"][names[0]]["streams"])
    lines = ["| `stream`, ±2 | " + " | ".join(kinds) + " |", "|---|" + "---|" * len(kinds)]
    rows = (("answered_right", "answered right"), ("mapped_right", "mapped right"),
            ("one_view_frames", "mapped frames at one view"),
            ("distinct_answered_right", "answered right, other frames"),
            ("distinct_mapped_right", "mapped right, other frames"))
    for part in (rows[:2], rows[2:]):
        for n in names:
            label = _dataset_label(n)
            for key, what in part:
                cells = [doc["datasets"][n]["streams"][k]["stream"]["2"].get(key) for k in kinds]
                lines.append(f"| {label} {what} | " + " | ".join(
                    "-" if v is None else str(v) if isinstance(v, int) else f"{v:.3f}" for v in cells) + " |")
    return "\n".join(lines)


def readme_table(doc: dict) -> str:
    """The README's results table from the ``results`` experiment's JSON: per derived stream, R@1 within ±2 / ±1
    of the ``stream`` matcher and online SeqSLAM on each dataset."""
    names = list(doc["datasets"])
    head = ["stream"] + [f"{_dataset_label(n)} {m}" for n in names
                         for m in ("`stream`", "online SeqSLAM")]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    kinds = list(doc["datasets"][names[0]]["streams"])
    for kind in kinds:
        cells = [STREAM_LABELS.get(kind, kind)]
        for n in names:
            for mode in ("stream", "seqslam-online"):
                f = doc["datasets"][n]["streams"][kind][mode]
                cells.append(f"{f['2']['r1']:.3f} / {f['1']['r1']:.3f}")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def replace_between(text: str, start: str, end: str, body: str, where: Path) -> str:
    """``text`` with what lies between the markers ``start`` and ``end`` replaced by ``body``; VprError naming
    ``where`` if a marker is missing."""
    if start not in text or end not in text:
        raise VprError(f"{where}: the markers {start.strip()} ... {end.strip()} are missing")
    head, rest = text.split(start, 1)
    _, tail = rest.split(end, 1)
    return head + start + body + end + tail
