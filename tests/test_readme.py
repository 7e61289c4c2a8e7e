"""The README and the docs as a reader meets them: every example runs as written, the commands are the ones CI
runs, the parameter table is the registry's, and nothing in them points at one machine or one issue."""
from __future__ import annotations

import csv
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
    """The main job's vpr-edge steps in a fresh folder, then the quick start's commands, which continue in that
    folder (as a reader runs them), then each Python block of the README in that folder."""
    main, _ = blocks(section(README, "Two commands"), "bash")
    job = [step.strip() for step in main.strip().split(" && ") if step.strip().startswith("vpr-edge ")]
    (quick,) = blocks(section(README, "Quick start"), "bash")
    commands = [line.split("  #")[0].strip() for line in quick.strip().splitlines()]
    assert "vpr-edge sample corridor" not in commands, "the quick start continues where the main job ended"
    for command in job + commands:
        proc = subprocess.run(["bash", "-c", command], cwd=tmp_path, capture_output=True, text=True, env=_env(),
                              timeout=300)
        assert proc.returncode == 0, (command, proc.stderr)
    written = (tmp_path / "corridor.matches.csv").read_text()
    assert written.count("\n") == 112
    # the README's example line is the line the quick start writes for that frame (its score to within the
    # rounding a machine's thread count moves: 2e-5 measured)
    (example,) = [b for b in blocks(section(README, "Quick start"), "") if b.startswith("frame_index")]
    want = dict(zip(*(line.split(",") for line in example.strip().splitlines())))
    got = next(row for row in csv.DictReader(written.splitlines()) if row["frame_index"] == want["frame_index"])
    assert {k: v for k, v in got.items() if k != "score"} == {k: v for k, v in want.items() if k != "score"}
    assert float(got["score"]) == pytest.approx(float(want["score"]), abs=1e-3)
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


def readme_commands(text: str) -> list[list[str]]:
    """Every command the README shows, as words: each ``&&`` step of each line of its bash blocks (comments
    dropped), and each inline code span that starts with a command or an option (wrapped lines joined)."""
    pieces = [step for block in blocks(text, "bash") for line in block.splitlines()
              for step in line.split("  #")[0].split("&&")]
    prose = re.sub(r"```.*?```", "", text, flags=re.S)
    pieces += [" ".join(span.split()) for span in re.findall(r"`([^`]+)`", prose)]
    return [piece.split() for piece in pieces if piece.strip()]


def _help(program: str, command: str) -> str:
    """The -h text of ``vpr-edge COMMAND`` or ``python -m vpr_edge_bench COMMAND``."""
    if program == "vpr-edge":
        from typer.testing import CliRunner

        from vpr_edge.cli import app

        res = CliRunner().invoke(app, [command, "-h"], terminal_width=200)
        assert res.exit_code == 0, (program, command, res.stderr)
        return res.stdout
    proc = subprocess.run([sys.executable, "-m", program, command, "-h"], cwd=ROOT, capture_output=True, text=True,
                          env=_env(), timeout=120)
    assert proc.returncode == 0, (program, command, proc.stderr)
    return proc.stdout


def _lists(help_text: str, option: str) -> bool:
    """``option`` is one of the options a -h text lists (at a line's start, alone, after a short form, or as
    the second name of an on/off pair: ``--standardise / --raw-cosines``)."""
    return re.search(rf"^\s*(?:-\w+, )*(?:--[\w-]+ / )?{re.escape(option)}(?=[\s,=/]|$)", help_text,
                     re.M) is not None


def test_every_readme_command_names_options_its_command_has() -> None:
    """Each vpr-edge or vpr_edge_bench command the README shows (a block's line, a code span such as
    ``localize --threads 1``) names only options its -h lists; an option shown alone (``--min-confidence``)
    is one some vpr-edge command, or an experiment the README runs, lists."""
    from vpr_edge.cli import app

    commands = [c.name for c in app.registered_commands]
    shown: list[tuple[tuple[str, str] | None, list[str]]] = []
    for words in readme_commands(README):
        if words[:3] == ["python", "-m", "vpr_edge_bench"] and len(words) > 3:
            shown.append((("vpr_edge_bench", words[3]), words[4:]))
        elif words[:3] == ["python", "-m", "vpr_edge"] and len(words) > 3 and words[3] in commands:
            shown.append((("vpr-edge", words[3]), words[4:]))
        elif words[0] == "vpr-edge" and len(words) > 1 and words[1] in commands:
            shown.append((("vpr-edge", words[1]), words[2:]))
        elif words[0] in commands:
            shown.append((("vpr-edge", words[0]), words[1:]))
        elif words[0].startswith("-"):
            shown.append((None, words))
    assert len(shown) > 30, shown
    helps = {key: _help(*key) for key in {k for k, _ in shown if k is not None} | {("vpr-edge", c) for c in commands}}
    wrong = []
    for key, args in shown:
        for option in (a.split("=")[0] for a in args if re.fullmatch(r"--?[A-Za-z][\w-]*(=.*)?", a)):
            where = [helps[key]] if key is not None else list(helps.values())
            if not any(_lists(h, option) for h in where):
                wrong.append(f"{' '.join(key) if key else 'any command'}: {option}")
    assert not wrong, wrong


def test_every_extra_the_readme_names_is_in_pyproject() -> None:
    import tomllib

    extras = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"])
    named = {e for group in re.findall(r"\.\[([\w,]+)\]", README) for e in group.split(",")}
    named |= set(re.findall(r"^\| `(\w+)` \|", README, re.M))          # the extras table's first column
    assert named and named <= extras, named - extras


def test_the_results_command_reads_only_what_it_is_given(tmp_path: Path) -> None:
    """The README's command that re-measures its results table, run as written from the repository root with
    DATASETS an empty folder: it reads its datasets from DATASETS (it names DATASETS/corridor as what is
    missing, in one line, exit 2, before any work), so in a fresh clone it needs nothing the README does not
    say; nothing is written."""
    (command,) = {" ".join(w) for w in readme_commands(section(README, "Results"))
                  if w[:4] == ["python", "-m", "vpr_edge_bench", "results"]}
    assert "--datasets DATASETS" in command
    argv = command.replace("DATASETS", str(tmp_path / "data")).replace("out/results", str(tmp_path / "out")).split()
    (tmp_path / "data").mkdir()
    before = (ROOT / "README.md").read_bytes()
    proc = subprocess.run([sys.executable, *argv[1:]], cwd=ROOT, capture_output=True, text=True, env=_env(),
                          timeout=120)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert str(tmp_path / "data" / "corridor") in proc.stderr, proc.stderr
    assert not (tmp_path / "out").exists() and (ROOT / "README.md").read_bytes() == before


def _heading_ids(text: str) -> set[str]:
    """The anchors GitHub gives a Markdown file's headings (lower case, punctuation dropped, spaces to hyphens)."""
    ids, fenced = set(), False
    for line in text.splitlines():
        fenced ^= line.startswith("```")
        if line.startswith("#") and not fenced:
            title = re.sub(r"^#+\s*", "", line).strip().lower()
            ids.add(re.sub(r"[^\w\- ]", "", title).replace(" ", "-"))
    return ids


def test_readme_is_a_front_door() -> None:
    assert README.count("\n") <= 150
    for link in re.findall(r"\]\((docs/[^)#]+)\)", README):
        assert (ROOT / link).is_file(), link
    for link, anchor in re.findall(r"\]\((docs/[^)#]+\.md)#([^)]+)\)", README):
        assert anchor in _heading_ids((ROOT / link).read_text()), f"{link}#{anchor}"


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
