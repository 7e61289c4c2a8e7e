"""``front-end-lines --frames``: a cached stream with every frame twice, or frames lost, against plain loops."""
from __future__ import annotations

import numpy as np
import pytest

from vpr_edge_bench.frame_edits import edited, parse


def case(n: int = 12, r: int = 9) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(1)
    truth = np.minimum(np.arange(n), r - 1)[:, None]
    return {"sim": rng.random((n, r)), "truth": truth, "cue": np.r_[np.nan, rng.uniform(-0.2, 0.2, n - 1)],
            "one_view": np.arange(n) % 5 == 0, "route": np.zeros(r, bool), "reach": np.int64(1),
            "tolerance": np.int64(2), "single_r1": np.float64(0.0), "single_r1_tol": np.float64(0.0)}


def test_every_frame_twice_repeats_the_rows_and_reads_each_copy_as_the_same_view():
    c = case()
    t = edited(c, "twice")
    for i in range(len(c["sim"])):
        for j in (2 * i, 2 * i + 1):
            np.testing.assert_array_equal(t["sim"][j], c["sim"][i])
            assert t["truth"][j, 0] == c["truth"][i, 0] and t["one_view"][j] == c["one_view"][i]
        assert t["cue"][2 * i + 1] == 1.0
        assert np.isnan(t["cue"][0]) if i == 0 else t["cue"][2 * i] == c["cue"][i]
    assert t["route"] is c["route"] and 0.0 <= t["single_r1"] <= t["single_r1_tol"] <= 1.0


def test_frames_lost_keep_the_first_and_the_rest_in_order():
    c = case(200)
    d = edited(c, "drop:0.25", seed=4)
    kept = [i for i in range(200) if any((c["sim"][i] == row).all() for row in d["sim"])]
    assert kept[0] == 0 and 100 < len(kept) < 190 and len(kept) == len(d["sim"])
    np.testing.assert_array_equal(d["truth"][:, 0], c["truth"][kept, 0])
    np.testing.assert_array_equal(d["cue"][1:], c["cue"][kept][1:])
    np.testing.assert_array_equal(edited(c, "drop:0.25", seed=4)["sim"], d["sim"])   # the seed fixes the draw
    assert edited(c, "as-recorded") is c


@pytest.mark.parametrize("bad", ["drop", "drop:0", "drop:1", "drop:x", "thrice", "twice:0.5"])
def test_bad_edits_are_refused(bad):
    with pytest.raises(ValueError, match="--frames must be one of"):
        parse(bad)
