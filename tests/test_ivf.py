"""The IVF index against an exhaustive search; the stream matcher searching around candidates against the
dense matcher; several windows in one compact pass against one pass each; build-map / localize with an index."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from helpers import alike_refs, driven_encodings, invoke
from vpr_edge.files.npz import read_npz, write_npz
from vpr_edge.index.encodings import Encodings
from vpr_edge.index.ivf import IvfIndex, fit_ivf
from vpr_edge.map import MAP_SCHEMA, load_map
from vpr_edge.matchers import MATCHERS, step
from vpr_edge.matchers.motion import stillness
from vpr_edge.matchers.road import RoadMatcher
from vpr_edge.matchers.stream_config import StreamConfig


def test_index_lists_every_place_once_and_finds_what_an_exhaustive_search_finds() -> None:
    refs = alike_refs(3000, 32)
    stored = Encodings.pack(refs, "int8")
    index = fit_ivf(stored, lists=40)
    assert np.array_equal(np.sort(index.order), np.arange(3000)) and index.offsets[-1] == 3000
    rng = np.random.default_rng(1)
    queries = refs[::97] + 0.05 * rng.normal(size=(len(refs[::97]), 32)).astype(np.float32)
    exact = stored.similarity(queries)
    for q, row in zip(queries, exact):
        every = index.candidates(stored, q, k=10, nprobe=40)   # every list: the exhaustive answer
        np.testing.assert_array_equal(np.sort(row[every]), np.sort(np.sort(row)[-10:]))
    found = [int(np.argmax(row)) in index.candidates(stored, q) for q, row in zip(queries, exact)]
    assert np.mean(found) >= 0.9


def test_index_from_arrays_refuses_what_does_not_fit() -> None:
    index = fit_ivf(Encodings.pack(alike_refs(200, 8), "float32"), lists=5)
    arrays = index.to_arrays()
    IvfIndex.from_arrays(arrays, 200, 8)
    for bad in ({"index_order": arrays["index_order"][:-1]}, {"index_order": arrays["index_order"] + 500},
                {"index_centroids": arrays["index_centroids"][:, :4]}):
        with pytest.raises(ValueError):
            IvfIndex.from_arrays(arrays | bad, 200, 8)


class OnePassEach(RoadMatcher):
    """The road matcher with its windows advanced one pass each over the whole-route state (the plain form of
    ``_advance_many``, which holds the state compact over the windows)."""

    def _advance_many(self, wins, z, gain, stop_decay, fed) -> None:
        self._densify()
        at = 0
        for lo, hi in wins:
            n = (hi - lo) * self.grid
            self._advance(lo * self.grid, hi * self.grid, z[at:at + n], gain, stop_decay, fed)
            at += n
        cols = self._state_cols(wins)
        self._hold(wins, cols, self._full[:, cols])


def test_compact_pass_equals_one_pass_per_window() -> None:
    rng = np.random.default_rng(2)
    sim = rng.normal(size=(60, 500))
    params = MATCHERS["stream-rules"].params | {"window": 0}
    a, b = RoadMatcher(500, StreamConfig.of(params)), OnePassEach(500, StreamConfig.of(params))
    for row in sim:
        cands = rng.choice(500, 12, replace=False)
        for m in (a, b):
            refs = m.around(cands)
            m.update(row[refs], refs)
        np.testing.assert_allclose(a.h, b.h, atol=1e-5)


def test_searching_around_candidates_answers_as_the_dense_matcher() -> None:
    refs, queries, truth = driven_encodings(5000, 400, noise=1.0, seed=3)
    stored = Encodings.pack(refs, "int8")
    index = fit_ivf(stored, lists=70)
    answers = {}
    cues = stillness(queries)   # as Localizer: the motion cue of the encodings, the map's stops and reach
    for name in ("dense", "index"):
        m = MATCHERS["stream"].on_route([refs]).stream(len(refs))
        out = []
        for q, cue in zip(queries, cues):
            cands = None if name == "dense" else (lambda q=q: index.candidates(stored, q))
            still = float(cue) if np.isfinite(cue) else None
            out.append(step(m, lambda idx, q=q: stored.similarity(q[None], idx)[0], still, cands))
        answers[name] = np.array(out)
    mapped, line = truth >= 0, MATCHERS["stream"].min_confidence
    for name, res in answers.items():
        right = (np.abs(res[:, 0] - truth) <= 2) & (res[:, 1] >= line)
        assert right[mapped][20:].mean() > 0.9, name
        assert (res[~mapped, 1] < line).mean() > 0.7, name
    same = np.abs(answers["dense"][:, 0] - answers["index"][:, 0]) <= 2
    assert same[mapped].mean() > 0.95


def test_build_map_indexes_and_localize_uses_it(tmp_path: Path) -> None:
    refs, queries, truth = driven_encodings(3000, 300, noise=1.0, seed=4)
    np.save(tmp_path / "refs.npy", refs)
    np.save(tmp_path / "stream.npy", queries)
    indexed, plain = tmp_path / "i.npz", tmp_path / "p.npz"
    assert invoke("build-map", tmp_path / "refs.npy", "-o", indexed, "--index", "ivf")[0] == 0
    assert invoke("build-map", tmp_path / "refs.npy", "-o", plain)[0] == 0
    assert load_map(indexed).index is not None and load_map(plain).index is None
    assert json.loads(invoke("info", indexed)[1])["index"]["kind"] == "ivf"
    lines = {}
    for m in (indexed, plain):
        code, out, err = invoke("localize", "-m", m, "-s", tmp_path / "stream.npy", "--format", "jsonl")
        assert code == 0, err
        lines[m] = [json.loads(x) for x in out.splitlines()]
    for m, got in lines.items():
        right = [x["ref_index"] is not None and abs(x["ref_index"] - t) <= 2 for x, t in zip(got, truth) if t >= 0]
        assert np.mean(right[20:]) > 0.9, m
    # appended drives keep a small map's index (rebuilt over every place)
    np.save(tmp_path / "more.npy", refs[:50])
    assert invoke("build-map", tmp_path / "more.npy", "-o", indexed, "--append")[0] == 0
    assert len(load_map(indexed).index) == 3050
    # an index that does not fit its map: one line naming the map
    arrays, meta = read_npz(indexed, "map", MAP_SCHEMA)
    arrays = {k: np.array(v) for k, v in arrays.items()} | {"index_order": np.zeros(5, np.int32)}
    write_npz(tmp_path / "bad.npz", arrays, meta)
    code, _, err = invoke("localize", "-m", tmp_path / "bad.npz", "-s", tmp_path / "stream.npy")
    assert code == 2 and err.count("\n") == 1 and "bad.npz" in err and "index" in err
    code, _, err = invoke("build-map", tmp_path / "refs.npy", "-o", tmp_path / "x.npz", "--index", "hnsw")
    assert code == 2 and err.count("\n") == 1 and "--index hnsw" in err and not (tmp_path / "x.npz").exists()


@pytest.mark.parametrize("mode, search", [("stream", "index"), ("stream", "coarse"), ("stream", "index"),
                                          ("stream", "coarse")])
def test_evaluate_answers_as_localize(tmp_path: Path, mode: str, search: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """``evaluate`` runs the per-frame search ``localize`` runs (``map.search``): on a map with an index its
    whole-route frames go through the index's candidates, on a long map (here: the length made short) through
    the coarse rows; every frame's answer and score are localize's, and evaluate asks the index or the coarse
    search as often as localize does (a plain count of the calls)."""
    from vpr_edge.index.coarse import CoarseSearch

    refs, queries, truth = driven_encodings(3000, 300, noise=1.0, seed=5)
    np.save(tmp_path / "refs.npy", refs)
    np.save(tmp_path / "stream.npy", queries)
    (tmp_path / "gt.csv").write_text("query,references\n" + "".join(
        f"{i},{'' if t < 0 else t}\n" for i, t in enumerate(truth)))
    path = tmp_path / "m.npz"
    assert invoke("build-map", tmp_path / "refs.npy", "-o", path, *(["--index", "ivf"] if search == "index" else []))[0] == 0
    calls: list[str] = []
    owner, name = (IvfIndex, "candidates") if search == "index" else (CoarseSearch, "similarity")
    real = getattr(owner, name)
    monkeypatch.setattr(owner, name, lambda self, *a, **k: calls.append("x") or real(self, *a, **k))
    if search == "coarse":
        monkeypatch.setattr("vpr_edge.map.search.COARSE_MIN_REFS", 1000)
    code, out, err = invoke("localize", "-m", path, "-s", tmp_path / "stream.npy", "--mode", mode, "--format", "jsonl")
    assert code == 0, err
    asked_by_localize = len(calls)
    got = [json.loads(x) for x in out.splitlines()]
    code, _, err = invoke("evaluate", "-m", path, "-q", tmp_path / "stream.npy", "--gt", tmp_path / "gt.csv",
                          "--modes", mode, "--answers", tmp_path / "answers.csv")
    assert code == 0, err
    assert len(calls) == 2 * asked_by_localize and asked_by_localize > 0
    rows = (tmp_path / "answers.csv").read_text().splitlines()[1:]
    assert len(rows) == len(got) == len(queries)
    for line, row in zip(got, rows):
        frame, _, ref, score, _, lost = row.split(",")[:6]
        assert float(score) == pytest.approx(line["score"], rel=1e-5, abs=1e-6), frame
        assert bool(int(lost)) == (line["ref_index"] is None), frame
        if line["ref_index"] is not None:
            assert int(ref) == line["ref_index"], frame
