"""Metrics against cases worked by hand and against scikit-learn where the definitions coincide."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vpr_edge.evaluation import metrics
from vpr_edge.evaluation.truth import pad


def curve_of(scores, correct, n_mapped):
    return metrics.pr_curve(np.array(scores, float), np.array(correct, bool), n_mapped)


def test_pr_curve_by_hand() -> None:
    # ranked: 0.9 ok, 0.8 wrong, 0.7 ok, 0.6 ok; 4 mapped queries
    c = curve_of([0.7, 0.9, 0.6, 0.8], [True, True, True, False], 4)
    np.testing.assert_allclose(c.precision, [1, 1 / 2, 2 / 3, 3 / 4])
    np.testing.assert_allclose(c.recall, [1 / 4, 1 / 4, 2 / 4, 3 / 4])
    np.testing.assert_allclose(c.thresholds, [0.9, 0.8, 0.7, 0.6])
    # eq. 5.1: recalls 1/4, 1/2, 3/4; min p at 1/4 = 1/2, max p at 1/2 = 2/3, at 3/4 = 3/4
    want = 0.25 * (0.5 + 2 / 3) / 2 + 0.25 * (2 / 3 + 3 / 4) / 2
    assert metrics.auc_trapezoid(c) == pytest.approx(want)
    # eq. 5.2: sum of (R_n - R_n-1) P_n
    assert metrics.average_precision(c) == pytest.approx(0.25 * 1 + 0 + 0.25 * 2 / 3 + 0.25 * 3 / 4)
    assert metrics.precision_at_full_recall(c) == 0.0            # recall 1 never reached
    assert metrics.recall_at_full_precision(c) == 0.25


def test_ties_are_accepted_together() -> None:
    c = curve_of([0.5, 0.5, 0.9], [True, False, True], 3)
    np.testing.assert_allclose(c.precision, [1, 2 / 3])
    np.testing.assert_allclose(c.recall, [1 / 3, 2 / 3])
    # a tie between a right and a wrong answer cannot give precision 1 at recall 2/3
    assert metrics.recall_at_full_precision(c) == pytest.approx(1 / 3)


def test_full_recall_and_precision() -> None:
    c = curve_of([0.9, 0.8, 0.7], [True, True, True], 3)
    assert metrics.precision_at_full_recall(c) == 1.0 and metrics.recall_at_full_precision(c) == 1.0
    # an unmapped query answered with high confidence is a false match
    c = curve_of([0.95, 0.9, 0.8], [False, True, True], 2)
    assert metrics.precision_at_full_recall(c) == pytest.approx(2 / 3)
    assert metrics.recall_at_full_precision(c) == 0.0


def test_against_sklearn_where_definitions_coincide() -> None:
    sk = pytest.importorskip("sklearn.metrics")
    rng = np.random.default_rng(3)
    scores = np.round(rng.uniform(size=200), 2)            # with ties
    correct = rng.uniform(size=200) < scores               # better scores are right more often
    n_mapped = int(correct.sum())                          # every mapped query's answer counted when right
    c = metrics.pr_curve(scores, correct, n_mapped)
    p, r, t = sk.precision_recall_curve(correct, scores)
    # sklearn lists thresholds ascending with a final (1, 0) point; ours descend
    keep = slice(None, -1)
    np.testing.assert_allclose(c.precision, p[keep][::-1])
    np.testing.assert_allclose(c.recall, r[keep][::-1])
    np.testing.assert_allclose(c.thresholds, t[::-1])
    assert metrics.average_precision(c) == pytest.approx(sk.average_precision_score(correct, scores))


def test_recall_at_k_and_tolerance() -> None:
    truth = pad([[5], [10, 11], [], [0]])
    ranked = np.array([[6, 1, 2], [3, 9, 11], [4, 5, 6], [9, 8, 0]])
    correct = metrics.correct_candidates(ranked, truth, tolerance=1)
    np.testing.assert_array_equal(correct, [[1, 0, 0], [0, 1, 1], [0, 0, 0], [0, 0, 1]])
    mapped = (truth >= 0).any(axis=1)
    assert metrics.recall_at_k(correct, mapped, 1) == pytest.approx(1 / 3)
    assert metrics.recall_at_k(correct, mapped, 2) == pytest.approx(2 / 3)
    assert metrics.recall_at_k(correct, mapped, 3) == 1.0
    assert metrics.correct_candidates(ranked, truth, 0)[0, 0] == 0
    err = metrics.localisation_error(ranked[:, 0], truth)
    np.testing.assert_array_equal(err[[0, 1, 3]], [1, 7, 9])
    assert np.isnan(err[2])


def naive_delays(region: np.ndarray, event: np.ndarray) -> list[float]:
    """Frame by frame: at each run start of ``region``, count frames until ``event`` or the run's end."""
    out, i = [], 0
    while i < len(region):
        if region[i] and (i == 0 or not region[i - 1]):
            j = i
            while j < len(region) and region[j] and not event[j]:
                j += 1
            out.append(float(j - i) if j < len(region) and region[j] else float("nan"))
        i += 1
    return out


def test_transition_delays_against_naive_loop() -> None:
    rng = np.random.default_rng(3)
    for _ in range(200):
        q = int(rng.integers(1, 40))
        mapped = rng.random(q) < rng.uniform(0.2, 1.0)
        found, lost = rng.random(q) < 0.3, rng.random(q) < 0.3
        lock, exits = metrics.transition_delays(mapped, found, lost)
        np.testing.assert_array_equal(lock, naive_delays(mapped, found))
        np.testing.assert_array_equal(exits, naive_delays(~mapped, lost))


def test_transition_delays_by_hand() -> None:
    mapped = np.array([1, 1, 1, 0, 0, 0, 1, 1, 0, 0], bool)
    found = np.array([0, 0, 1, 0, 0, 0, 0, 0, 0, 0], bool)     # locks at frame 2; never after the re-entry
    lost = np.array([0, 0, 0, 0, 1, 1, 0, 0, 1, 0], bool)      # lost one frame after leaving; at once the 2nd time
    lock, exits = metrics.transition_delays(mapped, found, lost)
    np.testing.assert_array_equal(lock, [2.0, np.nan])
    np.testing.assert_array_equal(exits, [1.0, 0.0])
    assert metrics.runs(np.array([], bool)) == [] and metrics.runs(np.ones(3, bool)) == [(0, 3)]


def test_reliability_known_answers() -> None:
    """Equal-width bins; ECE = sum of bin weight x |share right - mean confidence|, against a loop."""
    from vpr_edge.evaluation.metrics import reliability

    conf = np.array([0.8] * 10)
    ok = np.array([True] * 8 + [False] * 2)
    ece, table = reliability(conf, ok)
    assert ece == pytest.approx(0.0) and table == [{"from": 0.8, "to": 0.9, "n": 10, "confidence": 0.8,
                                                     "right": 0.8}]
    ece, _ = reliability(np.full(4, 0.9), np.array([True, False, True, False]))
    assert ece == pytest.approx(0.4)
    rng = np.random.default_rng(3)
    conf, ok = rng.random(500), rng.random(500) < 0.6
    conf[:3] = [0.0, 1.0, 0.1]                         # the edges: 1.0 falls in the last bin
    ece, table = reliability(conf, ok, bins=5)
    naive = 0.0
    for b in range(5):
        sel = [i for i in range(500) if min(int(conf[i] * 5), 4) == b]
        if sel:
            naive += len(sel) / 500 * abs(ok[sel].mean() - conf[sel].mean())
    assert ece == pytest.approx(naive) and sum(r["n"] for r in table) == 500
    assert np.isnan(reliability(np.zeros(0), np.zeros(0, bool))[0])


def test_brier_against_a_loop_and_a_constant() -> None:
    """Brier = mean squared (confidence - right); a constant at the share right p scores p (1 - p), whatever
    its ECE (0): the score that tells a confidence that ranks answers from one that does not."""
    from vpr_edge.evaluation.metrics import brier, reliability

    rng = np.random.default_rng(5)
    conf, ok = rng.random(300), rng.random(300) < 0.7
    assert brier(conf, ok) == pytest.approx(sum((c - float(o)) ** 2 for c, o in zip(conf, ok)) / 300)
    share = ok.mean()
    flat = np.full(300, share)
    assert brier(flat, ok) == pytest.approx(share * (1 - share)) and reliability(flat, ok)[0] == pytest.approx(0)
    assert brier(ok.astype(float), ok) == 0.0 and brier(np.full(3, 2.0), np.ones(3, bool)) == 0.0   # clipped
    assert np.isnan(brier(np.zeros(0), np.zeros(0, bool)))


def test_answered_shares_against_counts() -> None:
    from vpr_edge.evaluation.metrics import answered_shares

    correct = np.array([True, True, False, False, True, False])
    lost = np.array([False, True, False, True, False, False])
    mapped = np.array([True, True, True, True, True, False])
    right, found = answered_shares(correct, lost, mapped)
    assert right == pytest.approx(2 / 4)               # answered: 0, 2, 4, 5; right: 0, 4
    assert found == pytest.approx(2 / 5)
    assert np.isnan(answered_shares(correct, np.ones(6, bool), mapped)[0])


def test_calibration_recovers_a_known_curve_and_its_error_elsewhere() -> None:
    """Answers right with probability p(score) = score: the isotonic calibration recovers p, its ECE on fresh
    draws is near 0; on answers right with probability score**2 (another route) it is off by the known
    E|s - s**2| = 1/6 (s uniform on [0, 1])."""
    from vpr_edge.calibration import fit
    from vpr_edge.evaluation.metrics import reliability

    rng = np.random.default_rng(11)
    s = rng.random(20_000)
    curve = fit(s, rng.random(20_000) < s, tolerance=2, method="isotonic")
    grid = np.linspace(0.05, 0.95, 19)
    assert np.abs(np.array([curve(x) for x in grid]) - grid).max() < 0.06
    np.testing.assert_array_equal(curve.of(grid), [curve(x) for x in grid])     # the array form, the same values
    fresh = rng.random(20_000)
    conf = np.array([curve(x) for x in fresh])
    assert reliability(conf, rng.random(20_000) < fresh)[0] < 0.02
    ece_elsewhere = reliability(conf, rng.random(20_000) < fresh ** 2)[0]
    assert ece_elsewhere == pytest.approx(1 / 6, abs=0.02)


def test_logistic_calibration_against_scikit_learn_and_known_curves() -> None:
    """Platt scaling: a known logistic curve is recovered; its coefficients are scikit-learn's logistic
    regression with the same penalty on the slope; only the answers given are fitted; a score that says less
    when higher gives a flat curve at the share right; every answer right (or none) a finite, flat one."""
    from sklearn.linear_model import LogisticRegression

    from vpr_edge.calibration import fit, logistic

    rng = np.random.default_rng(5)
    s = rng.uniform(0, 2, 30_000)
    p = 1 / (1 + np.exp(-(4 * s - 3)))
    ok = rng.random(len(s)) < p
    a, b = logistic(s, ok)
    assert a == pytest.approx(4, abs=0.2) and b == pytest.approx(-3, abs=0.2)
    curve = fit(s, ok, tolerance=2)
    assert np.abs(curve.of(s[:1000]) - p[:1000]).max() < 0.03 and (np.diff(curve.confidence) >= 0).all()
    for ridge in (1e-3, 10.0):   # scikit-learn: 0.5 * |coef|^2 / C plus the log loss, the intercept free
        a, b = logistic(s[:3000], ok[:3000], ridge=ridge)
        ref = LogisticRegression(C=1 / ridge, tol=1e-12, max_iter=10_000).fit(s[:3000, None], ok[:3000])
        assert a == pytest.approx(ref.coef_[0, 0], rel=1e-4) and b == pytest.approx(ref.intercept_[0], rel=1e-4)
    # lost frames (answered False) do not move the fit
    lost = rng.random(len(s)) < 0.3
    given = fit(s, np.where(lost, ~ok, ok), 2, answered=~lost)
    assert given.n == int((~lost).sum()) and np.abs(given.of(s[:1000]) - p[:1000]).max() < 0.05
    # a higher score meaning less: flat at the share right; all right / none right: finite and flat
    flat = fit(s, ~ok, 2)
    assert np.ptp(flat.confidence) == 0 and flat.confidence[0] == pytest.approx((~ok).mean(), abs=1e-9)
    for labels, want in ((np.ones(len(s), bool), 30_001 / 30_002), (np.zeros(len(s), bool), 1 / 30_002)):
        c = fit(s, labels, 2)
        assert np.ptp(c.confidence) == 0 and c.confidence[0] == pytest.approx(want)
    assert fit(s, ok, 2, answered=np.zeros(len(s), bool)).n == 0
    with pytest.raises(ValueError, match="calibration method 'nope'"):
        fit(s, ok, 2, method="nope")


def test_distinct_shares_leave_out_one_view_frames() -> None:
    """``score_result`` with one-view frames: the distinct shares are the answered / mapped shares over the
    other frames (an unmapped frame counts among them), the count the one-view mapped frames."""
    from vpr_edge.evaluation.metrics import answered_shares
    from vpr_edge.evaluation.scoring import score_result
    from vpr_edge.matchers.base import Result

    rng = np.random.default_rng(5)
    q = 50
    truth = np.arange(q)[:, None].copy()
    truth[40:] = -1
    refs = np.where(rng.random(q) < 0.7, np.arange(q), (np.arange(q) + 7) % q)
    scores = rng.random(q)
    res = Result(refs, scores, refs[:, None])
    view = rng.random(q) < 0.3
    rep = score_result(res, truth, 0, 0.2, one_view=view)
    keep = ~view
    right = refs == truth[:, 0]
    exp = answered_shares(right[keep], (scores < 0.2)[keep], (truth[:, 0] >= 0)[keep])
    assert (rep.distinct_answered_right, rep.distinct_mapped_right) == pytest.approx(exp)
    assert rep.one_view_frames == int((view & (truth[:, 0] >= 0)).sum())
    plain = score_result(res, truth, 0, 0.2)
    assert plain.one_view_frames == -1 and np.isnan(plain.distinct_answered_right)


def test_calibration_line_against_a_plain_loop_and_through_its_file(tmp_path: Path) -> None:
    """A calibration's line: for a target precision, the lowest score whose answers at least as high (every
    answer, lost or not) were right that often by Wilson's 95% lower bound, against a plain loop over the
    thresholds; a drive too short to show the target gives no line; written and read back exactly; a file of
    schema 1 reads without one."""
    import json
    import math

    from vpr_edge.calibration import fit, line_points, load, write

    def wilson(k: int, n: int, z: float = 1.645) -> float:
        p = k / n
        return (p + z * z / (2 * n) - z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))) / (1 + z * z / n)

    assert wilson(57, 57) == pytest.approx(0.955, abs=5e-4) and wilson(150, 150) == pytest.approx(0.982, abs=5e-4)
    rng = np.random.default_rng(9)
    s = np.round(rng.uniform(0, 3, 400), 2)   # ties
    ok = rng.random(400) < s / 3
    curve = fit(s, ok, 2, answered=s > 1.0)   # the line ranks every answer, the curve the answers given
    for target in (0.5, 0.7, 0.8, 0.9, 0.95, 0.99, 1.0):
        reach = [t for t in sorted(set(s)) if wilson(int(ok[s >= t].sum()), int((s >= t).sum())) >= target - 1e-12]
        assert curve.line(target) == (reach[0] if reach else np.inf)
    assert fit(np.ones(57), np.ones(57, bool), 2).line(0.98) == np.inf   # 57 of 57 right do not show 0.98
    assert fit(np.arange(150.0), np.ones(150, bool), 2).line(0.98) == 0.0
    t, p = line_points(s, ok)
    assert (np.diff(t) > 0).all() and (np.diff(p) > 0).all() and curve.has_line
    assert line_points(np.zeros(0), np.zeros(0, bool))[0].size == 0
    write(tmp_path / "cal.json", {"stream": curve}, "test")
    back = load(tmp_path / "cal.json", "stream")
    assert all(back.line(x) == curve.line(x) for x in (0.5, 0.8, 0.9, 0.99))
    doc = json.loads((tmp_path / "cal.json").read_text())
    assert doc["schema"] == 2
    doc["schema"] = 1
    for m in doc["modes"].values():
        del m["line"]
    (tmp_path / "v1.json").write_text(json.dumps(doc))
    old = load(tmp_path / "v1.json", "stream")
    assert not old.has_line and old(1.5) == back(1.5)


def test_reliability_lines_show_each_bin_and_the_ece() -> None:
    """evaluate's reliability table: one row per bin any mode fills, '-' where a mode has none, the ECE."""
    from dataclasses import replace

    from vpr_edge.evaluation.report import reliability_lines
    from vpr_edge.evaluation.scoring import score_result
    from vpr_edge.matchers import Result

    conf = np.array([0.95, 0.95, 0.95, 0.95, 0.15])
    ece, bins = metrics.reliability(conf, np.array([True, True, True, False, False]))
    refs = np.arange(5)
    base = score_result(Result(refs=refs, scores=conf, ranked=refs[:, None]), pad([[0]] * 5))
    lines = reliability_lines({"a": replace(base, ece=ece, reliability=tuple(bins)), "b": base}, 4)
    assert lines[2].split() == ["confidence", "a"]                  # a mode without a table is left out
    assert lines[3].split() == ["0.1-0.2", "0.15", "->", "0.00", "(1)"]
    assert lines[4].split() == ["0.9-1.0", "0.95", "->", "0.75", "(4)"]
    assert lines[5].split() == ["ECE", f"{ece:.3f}"] and abs(ece - (0.8 * 0.2 + 0.2 * 0.15)) < 1e-9


def test_exact_and_lead_against_a_loop() -> None:
    """The truth's middle place, the share answered exactly there and the right answers' mean lead, against
    plain loops on random answers and truths (one place, a window, a window cut at the route's start, none)."""
    rng = np.random.default_rng(3)
    sets = [[int(c)] for c in rng.integers(0, 40, 30)] + \
        [list(range(max(0, c - 2), c + 3)) for c in rng.integers(0, 40, 30)] + [[]] * 5
    truth = pad(sets)
    refs = np.array([s[len(s) // 2] + int(rng.integers(-3, 4)) if s else 7 for s in sets])
    lost = rng.random(len(sets)) < 0.2
    right = metrics.correct_candidates(refs[:, None], truth, 1)[:, 0]
    mids = [(min(s) + max(s)) / 2 if s else None for s in sets]
    exact, lead = metrics.exact_and_lead(refs, truth, right, lost)
    mapped = [m for m in mids if m is not None]
    assert exact == sum(1 for r, m, x in zip(refs, mids, lost) if m is not None and not x and r == m) / len(mapped)
    near = [r - m for r, m, x, ok in zip(refs, mids, lost, right) if m is not None and not x and ok]
    assert abs(lead - sum(near) / len(near)) < 1e-12
    assert metrics.truth_middle(pad([[0, 1, 2]]))[0] == 1.0 and np.isnan(metrics.truth_middle(pad([[]]))[0])
