"""bench-scale and bench-frame time standardised encodings (``--standardise on|both``) on tiny data: both
variants' rows and their ratios are printed (no timing is asserted)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def bench_run(*args: str) -> subprocess.CompletedProcess:
    """``python -m vpr_edge_bench ARGS`` with the checkout on PYTHONPATH (as ``test_experiments``)."""
    env = os.environ | {"PYTHONPATH": os.pathsep.join([str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])}
    return subprocess.run([sys.executable, "-m", "vpr_edge_bench", *args], capture_output=True, text=True,
                          timeout=300, env=env)


def tool(name: str, *args: str) -> str:
    """The experiment ``name``'s stdout (it must succeed)."""
    proc = bench_run(name, *args)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout


def table(out: str) -> dict[str, str]:
    """bench-scale's markdown table -> {what: measured}."""
    return {r.split(" | ")[0].strip("| "): r.split(" | ")[1] for r in out.splitlines() if r.startswith("| ")}


def test_bench_scale_compares_plain_and_standardised(tmp_path: Path) -> None:
    out = tool("bench-scale", "--work", str(tmp_path), "--places", "2000", "--frames", "200", "--dim", "16",
               "--noise", "0.5", "--checkpoints", "100,200", "--standardise", "both", "--rounds", "2")
    rows = table(out)
    for label in ("plain", "standardised"):
        timed = rows["a frame's match (`push_encoding`), mean / p50 / p99 / max; max after the first 10 frames "
                     f"[{label}]"]
        assert float(timed.split(" / ")[0]) > 0
        assert "median of 2" in next(k for k in rows if k.startswith("`localize --threads 1`") and label in k)
    ratios = rows["standardised / plain: a frame's match (`push_encoding`), mean / p50 / p99"].split(" / ")
    assert len(ratios) == 3 and all(float(r) > 0 for r in ratios)
    cmd = rows["standardised / plain: `localize` ms a frame (whole command); peak RSS; RssAnon max"].split("; ")
    assert len(cmd) == 3 and all(float(r) > 0 for r in cmd)
    assert (tmp_path / "stream_2000x16_200_n0.5_s0.std.results.csv").is_file()   # localize --standardise ran


def test_bench_scale_standardised_alone(tmp_path: Path) -> None:
    out = tool("bench-scale", "--work", str(tmp_path), "--places", "500", "--frames", "100", "--dim", "16",
               "--noise", "0.5", "--checkpoints", "100", "--standardise", "on", "--mode", "stream-rules")
    rows = table(out)   # (stream-rules: on this short, weak drive the filter answers few frames)
    assert "standardise on" in out and not any(k.startswith("standardised / plain") for k in rows)
    assert float(rows["R@1 +-2 over mapped frames; answers given right; mapped frames answered right"]
                 .split(";")[0]) > 0.5


def test_bench_scale_refuses_no_rounds(tmp_path: Path) -> None:
    proc = bench_run("bench-scale", "--work", str(tmp_path), "--rounds", "0")
    assert proc.returncode == 2 and "--rounds >= 1" in proc.stderr


def test_bench_scale_runs_another_mode_and_refuses_an_offline_mode(tmp_path: Path) -> None:
    out = tool("bench-scale", "--work", str(tmp_path), "--places", "500", "--frames", "100", "--dim", "16",
               "--noise", "0.5", "--checkpoints", "100", "--mode", "stream-rules")
    assert "mode stream-rules" in out
    assert (tmp_path / "stream_500x16_100_n0.5_s0.stream-rules.std.results.csv").is_file()   # standardised: the default
    proc = bench_run("bench-scale", "--work", str(tmp_path / "w"), "--mode", "seqslam")
    errors = [ln for ln in proc.stderr.splitlines() if "error" in ln]
    assert proc.returncode == 2 and len(errors) == 1 and "--mode seqslam: not an online matcher" in errors[0]
    assert not (tmp_path / "w").exists()   # refused before the work


def test_bench_frame_compares_plain_and_standardised(tmp_path: Path, small_refs: Path) -> None:
    refs = tmp_path / "ref"
    refs.mkdir()
    for f in sorted(small_refs.iterdir())[:12]:
        (refs / f.name).symlink_to(f)
    m = tmp_path / "m.npz"
    build = subprocess.run([sys.executable, "-m", "vpr_edge", "build-map", str(refs), "-o", str(m),
                            "--components", "2"], capture_output=True, text=True, timeout=600)
    assert build.returncode == 0, build.stderr
    out = tool("bench-frame", "--map", str(m), "--frames", str(refs), "--threads", "1", "--repeat", "2",
               "--standardise", "both")
    lines = out.splitlines()
    plain, std = (lines[-3].split(), lines[-2].split())
    assert plain[-1] == "plain" and std[-1] == "standardised"
    assert all(float(v) > 0 for v in plain[1:6] + std[1:6])
    assert "standardised / plain: frame mean" in lines[-1] and "kB (plain / standardised)" in lines[-1]
