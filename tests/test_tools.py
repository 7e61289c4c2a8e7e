"""The measurement tools run and print what they promise (small sizes; no timing is asserted)."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def tool(name: str, *args: str) -> str:
    proc = subprocess.run([sys.executable, str(ROOT / "tools" / name), *args], capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout


def test_bench_matcher_reports_each_checkpoint() -> None:
    out = tool("bench_matcher.py", "--refs", "300", "--frames", "2000", "--dim", "32", "--checkpoints",
               "500,2000")
    rows = [line.split() for line in out.splitlines()[2:]]
    assert [r[0] for r in rows] == ["500", "2000"]
    assert all(float(r[-1]) > 0.8 for r in rows)          # synthetic route is followed
    assert all(float(r[4]) > 0 and float(r[5]) > 0 for r in rows)   # RSS columns are filled
