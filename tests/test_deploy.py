"""deploy/vpr-edge.service, the unit docs/deploy.md installs: one directive a line in its own section, restarts
that end on bad input, and an ExecStart whose vpr-edge options ``localize`` knows."""
from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
UNIT = ROOT / "deploy" / "vpr-edge.service"

# the directives this unit may use, by section (systemd would ignore one in the wrong section, with a warning)
KNOWN = {
    "Unit": {"Description", "Documentation", "After", "Wants", "Requires", "StartLimitIntervalSec",
             "StartLimitBurst"},
    "Service": {"Type", "User", "Group", "SupplementaryGroups", "LogsDirectory", "Environment", "ExecStart",
                "Restart", "RestartSec", "RestartPreventExitStatus", "SuccessExitStatus", "ProtectSystem",
                "ReadOnlyPaths", "ProtectHome", "PrivateTmp", "NoNewPrivileges"},
    "Install": {"WantedBy"},
}


def directives() -> dict[str, dict[str, str]]:
    """The unit as {section: {key: value}}; fails on a line that is neither a header nor one ``Key=value``."""
    out: dict[str, dict[str, str]] = {}
    section = None
    for n, line in enumerate(UNIT.read_text().splitlines(), 1):
        if not line.strip() or line.startswith(("#", ";")):
            continue
        if line.startswith("["):
            assert re.fullmatch(r"\[(\w+)\]", line), f"line {n}: a section header alone: {line!r}"
            section = line[1:-1]
            assert section in KNOWN and section not in out, f"line {n}: section {section}"
            out[section] = {}
            continue
        assert section is not None, f"line {n}: a directive before any section"
        key, sep, value = line.partition("=")
        assert sep and re.fullmatch(r"[A-Z][A-Za-z]+", key), f"line {n}: not Key=value: {line!r}"
        assert key in KNOWN[section], f"line {n}: {key} in [{section}]"
        assert key not in out[section], f"line {n}: {key} twice"
        if key != "ExecStart":      # two directives merged onto one line
            assert not re.search(r"\s[A-Z][A-Za-z]+=", value), f"line {n}: more than one directive: {line!r}"
        out[section][key] = value
    return out


def localize_command() -> list[str]:
    """ExecStart's shell command as the shell gets it ($$ and %% unescaped), in words."""
    program, *args = shlex.split(directives()["Service"]["ExecStart"])
    assert [program, args[0]] == ["/bin/sh", "-c"] and len(args) == 2, args
    script = args[1].replace("$$", "$").replace("%%", "%")
    subprocess.run(["sh", "-n", "-c", script], check=True)      # the shell's syntax
    words = shlex.split(script)
    assert words[:3] == ["exec", "/opt/vpr-edge/bin/vpr-edge", "localize"], words
    return words[3:]


def test_each_directive_has_its_own_line_in_its_section() -> None:
    unit = directives()
    assert set(unit) == set(KNOWN)
    assert unit["Service"]["User"] == "vpr-edge" and unit["Install"]["WantedBy"] == "multi-user.target"


def test_restarts_on_failure_within_a_limit_but_not_on_bad_input() -> None:
    unit = directives()
    service = unit["Service"]
    assert service["Restart"] == "on-failure"
    assert "2" in service["RestartPreventExitStatus"].split()          # bad input fails the same way again
    assert {"143", "130"} <= set(service["SuccessExitStatus"].split())  # SIGTERM, SIGINT: a clean stop
    assert int(unit["Unit"]["StartLimitBurst"]) >= 1
    assert int(unit["Unit"]["StartLimitIntervalSec"].rstrip("s")) > 0   # 0 would never give up


def test_execstart_options_are_localizes() -> None:
    words = localize_command()
    options = [w.split("=")[0] for w in words if w.startswith("-")]
    assert {"--map", "--stream", "--out"} <= set(options), options
    help_text = subprocess.run([sys.executable, "-m", "vpr_edge", "localize", "--help"], check=True,
                               capture_output=True, text=True, env={**os.environ, "COLUMNS": "200"}).stdout
    known = set(re.findall(r"(?<![\w-])--?[a-z][\w-]*", help_text))
    assert not [o for o in options if o not in known], f"not options of localize: {options}"
    value = dict(zip(words, words[1:]))
    assert value["--precision"] in ("fp32", "int8", "auto") and int(value["--threads"]) >= 0


def test_systemd_analyze_verify_prints_nothing() -> None:
    if shutil.which("systemd-analyze") is None:
        pytest.skip("systemd-analyze is not installed here (.ci/run installs it and runs this check)")
    proc = subprocess.run(["systemd-analyze", "verify", str(UNIT)], capture_output=True, text=True)
    assert proc.returncode == 0 and not (proc.stdout + proc.stderr).strip(), proc.stdout + proc.stderr
