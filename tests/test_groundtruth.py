"""Ground truth from the project's CSV, a boolean matrix and positions."""
from __future__ import annotations

import numpy as np
import pytest

from vpr_edge.evaluation import truth as groundtruth
from vpr_edge.errors import VprError


def test_csv_with_unmapped_rows(tmp_path) -> None:
    p = tmp_path / "gt.csv"
    p.write_text("query,references\n0,0 1\n1,\n2,4\n")
    np.testing.assert_array_equal(groundtruth.load_csv(p), [[0, 1], [-1, -1], [4, -1]])
    p.write_text("query,references\n0,1\n2,3\n")
    with pytest.raises(VprError, match="without gaps"):
        groundtruth.load_csv(p)
    p.write_text("a,b\n")
    with pytest.raises(VprError, match="header"):
        groundtruth.load_csv(p)


def test_matrix(tmp_path) -> None:
    m = np.zeros((3, 5), bool)
    m[0, [1, 2]] = m[2, 4] = True
    np.save(tmp_path / "gt.npy", m)
    np.testing.assert_array_equal(groundtruth.load_matrix(tmp_path / "gt.npy"), [[1, 2], [-1, -1], [4, -1]])
    np.save(tmp_path / "bad.npy", np.zeros(3))
    with pytest.raises(VprError, match="2-D"):
        groundtruth.load_matrix(tmp_path / "bad.npy")


def test_positions_metric_and_geographic(tmp_path) -> None:
    (tmp_path / "r.csv").write_text("x,y\n0,0\n10,0\n20,0\n")
    (tmp_path / "q.csv").write_text("x,y\n9,0\n100,0\n")
    np.testing.assert_array_equal(groundtruth.from_positions(tmp_path / "r.csv", tmp_path / "q.csv", 5),
                                  [[1], [-1]])
    # 0.0001 degrees of latitude is about 11.1 m
    (tmp_path / "rg.csv").write_text("lat,lon\n52.0,13.0\n52.0001,13.0\n52.001,13.0\n")
    (tmp_path / "qg.csv").write_text("lat,lon\n52.00005,13.0\n")
    np.testing.assert_array_equal(groundtruth.from_positions(tmp_path / "rg.csv", tmp_path / "qg.csv", 6),
                                  [[0, 1]])
    with pytest.raises(VprError, match="same columns needed"):
        groundtruth.from_positions(tmp_path / "r.csv", tmp_path / "qg.csv", 5)


def test_ground_truth_as_spreadsheets_write_it(tmp_path) -> None:
    """Excel / LibreOffice: a byte-order mark, CRLF line ends, blank lines and rows of empty cells read as the
    plain file does; a query's second row is refused naming its line (and whether it contradicts the first)."""
    plain = tmp_path / "plain.csv"
    plain.write_text("query,references\n0,0 1\n1,\n2,2\n")
    sheet = tmp_path / "sheet.csv"
    sheet.write_bytes(b"\xef\xbb\xbfquery,references\r\n0,0 1\r\n\r\n1,\r\n,\r\n2,2\r\n,\r\n\r\n")
    np.testing.assert_array_equal(groundtruth.load_csv(sheet), groundtruth.load_csv(plain))
    twice = tmp_path / "twice.csv"
    twice.write_text("query,references\n0,0\n1,1\n0,0\n")
    with pytest.raises(VprError, match=r"twice.csv: line 4: query 0 has a row already \(line 2\)$"):
        groundtruth.load_csv(twice)
    clash = tmp_path / "clash.csv"
    clash.write_text("query,references\n0,0\n1,1\n1,5\n")
    with pytest.raises(VprError, match="line 4: query 1 has a row already .line 3., with other references"):
        groundtruth.load_csv(clash)


def test_one_view_frames_against_a_naive_loop() -> None:
    """A frame is one-view where any of its truth references lies in a run of references showing the view of
    the one before, or is the reference that run repeats; unmapped rows never are."""
    rng = np.random.default_rng(3)
    same = rng.random(40) < 0.3
    truth = rng.integers(-1, 40, size=(60, 3))
    truth[:5] = -1
    runs = set()
    for r in range(40):
        if same[r]:
            runs.update({r, r - 1} if r else {r})
    naive = [any(int(t) in runs for t in row if t >= 0) for row in truth]
    np.testing.assert_array_equal(groundtruth.one_view(truth, same), naive)
    assert not groundtruth.one_view(truth, same)[:5].any()


def test_written_ground_truth_reads_back(tmp_path) -> None:
    """``write_ground_truth`` writes what ``load_csv`` reads: several references, none (not in the map)."""
    path = tmp_path / "gt.csv"
    groundtruth.write_ground_truth(path, [[3], [], [4, 5]])
    assert path.read_text() == "query,references\n0,3\n1,\n2,4 5\n"
    np.testing.assert_array_equal(groundtruth.load_csv(path), [[3, -1], [-1, -1], [4, 5]])
