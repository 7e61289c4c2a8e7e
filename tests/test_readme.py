"""The README and the docs as a reader meets them: every example runs as written, the commands are the ones CI
runs, the parameter table is the registry's, and nothing in them points at one machine or one issue."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "README.md").read_text()


def blocks(text: str, lang: str) -> list[str]:
    """The fenced code blocks of ``text`` whose info string is ``lang`` ("" for plain fences)."""
    out, current, kind = [], None, None
    for line in text.splitlines():
        if line.startswith("```"):
            if current is None:
                current, kind = [], line[3:].strip()
            else:
                if kind == lang:
                    out.append("\n".join(current) + "\n")
                current = None
        elif current is not None:
            current.append(line)
    return out


def section(text: str, title: str) -> str:
    start = text.index(f"## {title}\n")
    end = text.find("\n## ", start + 1)
    return text[start:end if end > 0 else None]


def _env() -> dict[str, str]:
    return os.environ | {"PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}


@pytest.mark.slow
def test_quick_start_and_every_python_block_run_as_written(tmp_path: Path) -> None:
    """The quick start's commands, in a fresh folder, then each Python block of the README in that folder."""
    (quick,) = blocks(section(README, "Quick start"), "bash")
    for line in quick.strip().splitlines():
        command = line.split("  #")[0].strip()
        proc = subprocess.run(["bash", "-c", command], cwd=tmp_path, capture_output=True, text=True, env=_env(),
                              timeout=300)
        assert proc.returncode == 0, (command, proc.stderr)
    assert (tmp_path / "corridor.matches.csv").read_text().count("\n") == 112
    python = blocks(README, "python")
    assert python, "the README has a Python example"
    for code in python:
        proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True,
                              env=_env(), timeout=300)
        assert proc.returncode == 0, proc.stderr
        assert "last frame:" in proc.stdout


def test_output_line_example_has_the_csv_columns() -> None:
    from vpr_edge.outputs.log import CSV_COLUMNS

    (example,) = [b for b in blocks(section(README, "Quick start"), "") if b.startswith("frame_index")]
    header, line = example.strip().splitlines()
    assert header.split(",") == list(CSV_COLUMNS) and len(line.split(",")) == len(CSV_COLUMNS)


def test_the_two_commands_are_what_ci_runs() -> None:
    main, tests = blocks(section(README, "Two commands"), "bash")
    ci = (ROOT / ".ci" / "run").read_text()
    assert tests.strip() in ci.splitlines()
    # the main job's vpr-edge steps run in CI from the installed wheel, outside the checkout
    steps = main.strip().split(" && ")
    assert steps[-3:] == ["vpr-edge sample corridor", "vpr-edge build-map corridor/ref -o corridor.map.npz",
                          "vpr-edge localize -m corridor.map.npz -s corridor/query -o corridor.matches.csv"]
    assert " && ".join(steps[-3:]) in ci


def test_readme_is_a_front_door() -> None:
    assert README.count("\n") <= 300
    for link in re.findall(r"\]\((docs/[^)#]+)\)", README):
        assert (ROOT / link).is_file(), link


@pytest.mark.parametrize("doc", [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))],
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_docs_name_no_issue_nor_one_machines_path(doc: Path) -> None:
    text = doc.read_text()
    assert not re.search(r"\bissue\s*#?\d|#\d{1,3}\b", text, re.I), doc
    assert "../shared" not in text and "/work/" not in text and "/tmp/" not in text, doc


def test_matcher_parameter_table_is_the_registrys() -> None:
    from vpr_edge.matchers.registry import params_table

    text = (ROOT / "docs" / "matchers.md").read_text()
    table = text.split("<!-- params table: generated -->\n")[1].split("\n<!-- end of params table -->")[0]
    assert table == params_table(), "regenerate with: python -m vpr_edge.matchers"


def test_formats_names_the_header_localize_writes() -> None:
    """docs/formats.md and the README show the CSV header ``localize`` writes (``api.FIELDS``)."""
    from vpr_edge.api import FIELDS

    header = ",".join(FIELDS)
    assert f"`{header}`" in (ROOT / "docs" / "formats.md").read_text()
    assert f"\n{header}\n" in (ROOT / "README.md").read_text()


def test_readme_results_table_is_the_last_regenerated_one() -> None:
    """The README's results table and docs/results.md's answered-right table are exactly what
    ``python -m vpr_edge_bench results --write-docs`` wrote from the figures it measured
    (docs/generated/results.json): no number in them is typed by hand or left from an older run."""
    import json

    from vpr_edge_bench.doc_tables import TABLE_END, TABLE_START, answers_table, readme_table

    doc = json.loads((ROOT / "docs" / "generated" / "results.json").read_text())
    for name, table in (("README.md", readme_table(doc)), ("docs/results.md", answers_table(doc))):
        text = (ROOT / name).read_text()
        block = text.split(TABLE_START)[1].split("\n" + TABLE_END)[0]
        assert block == table, f"{name}: regenerate it (python -m vpr_edge_bench results --quick --write-docs)"


def test_references_to_results_md_name_its_sections() -> None:
    """Every ``docs/results.md, "SECTION"`` (or ``"SECTION" in docs/results.md``) in the code and the docs names a
    heading that results.md has, so that a rewrite of results.md leaves no reader pointed at nothing."""
    heads = [re.sub(r"^#+\s*", "", line).strip() for line in (ROOT / "docs" / "results.md").read_text().splitlines()
             if line.startswith("#")]
    sources = [*(ROOT / "vpr_edge").rglob("*.py"), *(ROOT / "vpr_edge_export").rglob("*.py"),
               *(ROOT / "tools").glob("*.py"), *(ROOT / "docs").glob("*.md"), ROOT / "README.md"]
    named = re.compile(r'results\.md\)?,?\s*"([A-Za-z][^"]{0,79})"|"([^"]{1,80})" in docs/results\.md')
    wrong = []
    for path in sources:
        for m in named.finditer(path.read_text()):
            name = re.sub(r"\s*\n\s*#?\s*", " ", m.group(1) or m.group(2)).strip()
            if not any(h == name or h.startswith(name) for h in heads):
                wrong.append(f"{path.relative_to(ROOT)}: {name!r}")
    assert not wrong, wrong
