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


def _report(refs: list[int], correct: list[bool], lost: list[bool]):
    """A mode's report over len(refs) frames, each answered ``refs[i]``, right / lost as given."""
    import numpy as np

    from vpr_edge.evaluation.metrics import pr_curve
    from vpr_edge.evaluation.scoring import ModeReport

    scores = np.linspace(1.0, 0.5, len(refs))
    c = np.array(correct)
    return ModeReport(recall={1: float(c.mean())}, auc=0.9, ap=0.9, precision_at_full_recall=0.9,
                      recall_at_full_precision=0.5, median_error=0.0, lost_unmapped=float("nan"),
                      lost_mapped=0.0, match_ms=0.1, curve=pr_curve(scores, c, len(refs)), refs=np.array(refs),
                      lost=np.array(lost), correct=c, scores=scores)


def test_precision_floor_is_a_little_below_the_lowest_useful_precision() -> None:
    import numpy as np

    from vpr_edge.evaluation.figures import precision_floor

    high = (np.array([0.2, 0.5, 0.9]), np.array([1.0, 0.98, 0.96]))
    low = (np.array([0.01, 0.3, 0.6]), np.array([0.0, 0.83, 0.82]))     # a first answer wrong: left out
    assert precision_floor([high]) == 0.95
    assert precision_floor([high, low]) == 0.8
    assert precision_floor([(np.array([0.02, 0.05]), np.array([0.0, 0.5]))]) == 0.45   # never at useful recall
    assert precision_floor([(np.array([0.5]), np.array([1.0]))]) == 0.95 and precision_floor([]) == 0.0


def test_route_limits_frame_the_route_and_widen_a_straight_one() -> None:
    import numpy as np

    from vpr_edge.evaluation.figures import route_limits

    (x0, x1), (y0, y1) = route_limits(np.array([[0.0, 0.0], [0.0, 55.0], [np.nan, np.nan]]))
    assert (y0, y1) == pytest.approx((-2.75, 57.75))
    assert (x0, x1) == pytest.approx((-9.625, 9.625))              # a quarter of the length, and the margin
    (x0, x1), (y0, y1) = route_limits(np.array([[100.0, 10.0], [300.0, 110.0]]))
    assert (x0, x1, y0, y1) == pytest.approx((90.0, 310.0, 0.0, 120.0))
    assert route_limits(np.array([[3.0, 4.0]])) == ((-2.5, 8.5), (-1.5, 9.5))     # one place: 10 m about it


def test_answers_are_counted_right_wrong_lost() -> None:
    from vpr_edge.evaluation.figures import answer_kinds, counts_text

    kinds = answer_kinds(_report([0, 1, 5, 3], [True, True, False, True], [False, False, False, True]))
    assert [list(kinds[k]) for k in ("right", "wrong", "lost")] == [[True, True, False, False],
                                                                      [False, False, True, False],
                                                                      [False, False, False, True]]
    assert counts_text("stream", kinds) == "stream: 2 right, 1 wrong, 1 lost"
    assert counts_text("dtw", kinds, "\n") == "dtw\n2 right, 1 wrong, 1 lost"


def test_grids_stay_compact() -> None:
    from vpr_edge.evaluation.figures import MAX_HEIGHT_IN, MAX_WIDTH_IN, grid_layout

    for n in range(1, 13):
        for aspect in (0.2, 0.32, 1.0, 1.3, 3.0):
            cols, rows, w, h = grid_layout(n, aspect)
            assert cols * rows >= n and rows * h <= MAX_HEIGHT_IN + 1e-6 and (cols == 1 or cols * w <= MAX_WIDTH_IN)
            assert cols * rows - n < cols, (n, aspect)                  # never a whole empty row
    assert grid_layout(4, 1.3)[:2] == (2, 2) and grid_layout(10, 0.32)[:2] == (5, 2)


def test_figures_are_drawn_small_and_readable(tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    import cv2
    import numpy as np

    from vpr_edge.evaluation.figures import plot, plot_matrix, plot_route
    from vpr_edge.positions import Positions

    q = 30
    truth = np.array([[i] for i in range(q)])
    reports = {m: _report([i if i % k else (i + 7) % q for i in range(q)], [bool(i % k) for i in range(q)],
                          [i % 11 == 5 for i in range(q)]) for m, k in (("stream", 9), ("single", 4), ("dtw", 50))}
    nan = np.full(q, np.nan)
    route = Positions(np.stack([np.zeros(q), np.arange(q) * 2.0], 1), "local", nan, nan)
    sim = np.random.default_rng(0).random((q, q))
    drawn = {"pr.png": lambda p: plot(p, reports, "t"), "m.png": lambda p: plot_matrix(p, sim, truth, reports, "t"),
             "r.png": lambda p: plot_route(p, route, truth, reports, "t"),
             "f.png": lambda p: plot_route(p, None, truth, reports, "t")}
    for name, draw in drawn.items():
        draw(tmp_path / name)
        image = cv2.imread(str(tmp_path / name))
        assert image is not None and image.std() > 10 and 300 < image.shape[1] <= 1600, name
        assert (tmp_path / name).stat().st_size < 200 * 1024, name
