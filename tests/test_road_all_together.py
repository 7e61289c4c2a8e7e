"""The stream matcher's trajectories with every part at once (a map of several drives with junctions, the
motion cue and the map's own stops, the local search around a firm lock, an index's candidates) against the
recursion written as plain loops (``helpers.naive_road_all``): the answer, its trajectory score, the whole
state and the references read, frame by frame."""
from __future__ import annotations

import numpy as np
import pytest

from vpr_edge.map.drives import Drives
from vpr_edge.matchers import MATCHERS
from vpr_edge.matchers.base import step
from vpr_edge.matchers.road import RoadMatcher
from vpr_edge.matchers.stream_config import StreamConfig
from vpr_edge.matchers.route import RouteGraph

from helpers import naive_road_all


@pytest.mark.parametrize("seed", [0, 1])
def test_every_part_together_against_plain_loops(seed: int) -> None:
    rng = np.random.default_rng(seed)
    drives = Drives.of(["a", "b", "c"], [30, 25, 25])
    graph = RouteGraph(drives.n_refs, drives.starts, tuple(drives.junctions()) + ((np.array([12]), np.array([62])),))
    n = drives.n_refs
    # a drive along a (from 3), on into c's middle through the added junction, then b from its start
    path = [float(p) for p in np.arange(3, 13)] + [float(p) for p in np.arange(62, 80, 1.5)] + \
        [float(p) for p in np.arange(30, 55)]
    frames, cues = [], []
    for k, p in enumerate(path):
        row = rng.normal(0.0, 0.4, n)
        row[int(p)] += 1.5
        frames.append(row)
        cues.append(np.nan if k % 11 == 5 else 0.1)
        if k in (6, 20, 35):   # the camera stands: the same view again, three frames
            for _ in range(3):
                frames.append(row + rng.normal(0.0, 0.02, n))
                cues.append(0.95)
    sim = np.asarray(frames)
    route = np.zeros(n, bool)
    route[44:46] = True   # the mapping drive stood there, just after the third stop
    candidates = [None if k % 4 == 0 else np.r_[np.argsort(-row)[:3], rng.integers(0, n)] for k, row in enumerate(sim)]
    params = MATCHERS["stream-rules"].params | dict(vmax=2.0, grid=2, decay=0.9, bias=0.5, turn=0.5, memory=20.0,
                                              lock=2.0, hold=2.0, window=6, probe=20, check=7, span=2, seek=2,
                                              peaks=2, still=0.5, rival_window=3)
    m = RoadMatcher(n, StreamConfig.of(params), route=route, graph=graph)
    want = naive_road_all(sim, graph, np.asarray(cues), route, candidates, **params)
    local = index = 0
    for k, row in enumerate(sim):
        asked = m.wanted()
        cue = None if np.isnan(cues[k]) else cues[k]
        cands = None if candidates[k] is None else (lambda c=candidates[k]: c)
        read: list = []
        ref, _ = step(m, lambda idx, row=row: (read.append(idx), row if idx is None else row[idx])[1], cue, cands)
        w_ref, w_best, w_h, w_read = want[k]
        assert (ref, round(m.best(), 3)) == (w_ref, round(w_best, 3)), k
        assert (read[0] is None) == (w_read is None) and (w_read is None or read[0].tolist() == w_read), k
        np.testing.assert_allclose(m.h, w_h, atol=1e-3, err_msg=str(k))
        local += asked is not None
        index += asked is None and cands is not None
    assert local > 10 and index > 5   # both searches ran
