"""The figures a person reads (``evaluation.report``): titles by base names, and docs/img/ re-made by one
command (``python -m vpr_edge_bench doc-figures``), each small."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from vpr_edge.evaluation.report import figure_title

ROOT = Path(__file__).resolve().parent.parent


def test_titles_name_the_files_not_their_paths() -> None:
    assert figure_title((111, 110), map_path=Path("/home/someone/maps/route.npz"), queries="/data/drives/query/") == \
        "map route.npz, stream query (111 queries, 110 references)"
    assert figure_title((5, 6), similarity="/x/y/sim.npy") == "similarity sim.npy (5 queries, 6 references)"
    assert figure_title((5, 6), refs="a/ref", queries="a/q") == "references ref, stream q (5 queries, 6 references)"


@pytest.mark.slow
def test_doc_figures_remakes_small_pngs(tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    import cv2

    proc = subprocess.run([sys.executable, "-m", "vpr_edge_bench", "doc-figures", "--out", str(tmp_path)],
                          capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    pngs = sorted(tmp_path.glob("*.png"))
    assert [p.name for p in pngs] == ["corridor_matrix.png", "corridor_pr.png", "corridor_route.png"]
    for png in pngs:
        image = cv2.imread(str(png))
        assert png.stat().st_size < 150 * 1024 and min(image.shape[:2]) > 300 and image.std() > 10, png.name
    assert sorted(p.name for p in (ROOT / "docs" / "img").glob("*.png")) == [p.name for p in pngs]  # what docs show
