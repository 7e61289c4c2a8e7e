"""``vpr-edge adapt`` (``encoders.adapt``, ``map.adapt``): the fit against plain loops on planted places, an
adapted map saved and loaded, and every refusal in one line with nothing written."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from helpers import invoke

from vpr_edge.encoders.adapt import Adaptation, fit_within_place, middle_refs, rank_for
from vpr_edge.map.io import MAP_SCHEMA, load_map
from vpr_edge.files.npz import read_npz, write_npz
from vpr_edge.map import MapQuery

DIM, SIGNAL, PLACES = 32, 24, 160   # dims SIGNAL.. DIM-1 carry the conditions (a season), not the place


def _unit(x: np.ndarray) -> np.ndarray:
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def planted(seed: int = 0, places: int = PLACES) -> tuple[np.ndarray, np.ndarray]:
    """(references, queries) (places, DIM): each place a direction in the first SIGNAL dims; both drives see it
    with a little noise, and each frame with a strong condition of its own in the last dims."""
    rng = np.random.default_rng(seed)
    place = rng.normal(size=(places, SIGNAL))

    def drive() -> np.ndarray:
        seen = place + 0.3 * rng.normal(size=place.shape)
        return np.hstack([seen, 4.0 * rng.normal(size=(places, DIM - SIGNAL))]).astype(np.float32)

    return drive(), drive()


def r1(queries: np.ndarray, refs: np.ndarray) -> float:
    return float(np.mean(np.argmax(_unit(queries) @ _unit(refs).T, axis=1) == np.arange(len(queries))))


def test_the_fit_is_a_plain_loops() -> None:
    refs, queries = planted(1, 80)
    got = fit_within_place(queries, refs, rank=6, shrink=0.2)
    scatter = np.zeros((DIM, DIM))
    for q, r in zip(queries.astype(np.float64), refs.astype(np.float64)):
        d = q / np.linalg.norm(q) - r / np.linalg.norm(r)
        scatter += np.outer(d, d) / len(refs)
    var, vec = np.linalg.eigh(scatter)
    var, vec = var[::-1], vec[:, ::-1]
    floor = 0.2 * var[:6].mean()
    np.testing.assert_allclose(got.keep, np.sqrt(floor / (var[:6] + floor)), rtol=1e-4)
    for i in range(6):   # each direction up to its sign
        assert abs(float(got.basis[i] @ vec[:, i])) > 0.999
    x = np.random.default_rng(2).normal(size=(5, DIM))
    w = np.eye(DIM) - vec[:, :6] @ np.diag(1 - np.sqrt(floor / (var[:6] + floor))) @ vec[:, :6].T
    np.testing.assert_allclose(got.apply(x), _unit(x @ w), atol=1e-5)


def test_planted_conditions_are_found_and_suppressed() -> None:
    refs, queries = planted(0)
    half = PLACES // 2
    ad = fit_within_place(queries[:half], refs[:half], rank=DIM - SIGNAL)
    assert np.linalg.norm(ad.basis[:, SIGNAL:], axis=1).min() > 0.95   # the condition dims, not the place's
    assert (ad.keep < 0.4).all()   # each shrunk to about sqrt(shrink / (1 + shrink)) of its length
    before, after = r1(queries[half:], refs[half:]), r1(ad.apply(queries[half:]), ad.apply(refs[half:]))
    assert after > before + 0.3 and after > 0.8, (before, after)   # places never learned from


def test_each_frame_pairs_with_the_middle_of_its_truth() -> None:
    truth = np.array([[3, 1, 2], [7, -1, -1], [-1, -1, -1], [5, 4, -1]])
    assert middle_refs(truth).tolist() == [2, 7, -1, 4]
    assert rank_for(30) == 7 and rank_for(400) == 80 and rank_for(2) == 1


def test_a_stored_adaptation_is_checked() -> None:
    ad = fit_within_place(*planted(3, 60), rank=4)
    again = Adaptation.from_arrays(ad.to_arrays(), DIM)
    np.testing.assert_array_equal(again.basis, ad.basis)
    with pytest.raises(ValueError, match="do not fit"):
        Adaptation.from_arrays(ad.to_arrays(), DIM + 1)
    with pytest.raises(ValueError, match="orthonormal"):
        Adaptation.from_arrays(ad.to_arrays() | {"adapt_basis": 2 * ad.basis}, DIM)
    with pytest.raises(ValueError, match="keeps outside"):
        Adaptation.from_arrays(ad.to_arrays() | {"adapt_keep": ad.keep * 0}, DIM)


@pytest.fixture()
def drive(tmp_path: Path) -> Path:
    """A map of descriptors (PLACES places, int8) and an aligned labelled drive of them, in ``tmp_path``."""
    refs, queries = planted(0)
    np.save(tmp_path / "refs.npy", refs)
    np.save(tmp_path / "drive.npy", queries)
    np.save(tmp_path / "short.npy", queries[:40])
    rows = "\n".join(f"{i},{i}" for i in range(PLACES))
    (tmp_path / "drive.csv").write_text("query,references\n" + rows + "\n")
    code, _, err = invoke("build-map", tmp_path / "refs.npy", "-o", tmp_path / "map.npz")
    assert code == 0, err
    return tmp_path


def test_an_adapted_map_saved_and_loaded_gives_the_same_answers(drive: Path) -> None:
    code, _, err = invoke("adapt", drive / "map.npz", drive / "drive.npy", "--aligned", "-o", drive / "a.npz")
    assert code == 0, err
    assert "160 labelled frames" in err
    plain, opened = load_map(drive / "map.npz"), MapQuery(drive / "a.npz")
    adapted = opened.map
    assert adapted.meta["schema"] == MAP_SCHEMA and adapted.stored.storage == plain.stored.storage
    assert adapted.meta["adapted"]["pairs"] == PLACES and adapted.adaptation is not None
    queries = np.load(drive / "drive.npy")
    # the stored rows are the adaptation of the plain map's, and each query is mapped as encoded
    expect = adapted.adaptation.apply(plain.stored.dense()) @ adapted.adaptation.apply(queries).T
    got = adapted.similarity(opened.encode_descriptors(queries))
    np.testing.assert_allclose(got, expect.T, atol=0.02)   # int8 rows
    assert (got.argmax(axis=1) == expect.T.argmax(axis=1)).mean() > 0.95
    # localize and evaluate answer through the mapped encodings; info says what it was adapted on
    code, out, err = invoke("localize", "-m", drive / "a.npz", "-s", drive / "drive.npy", "--mode", "single")
    assert code == 0, err
    answers = [int(line.split(",")[3]) for line in out.splitlines()[1:]]
    assert answers == got.argmax(axis=1).tolist()
    code, out, _ = invoke("info", drive / "a.npz")
    assert code == 0 and '"adapted_on"' in out and "drive.npy labelled by aligned: 160 frames" in out


def test_drives_labelled_by_position(drive: Path) -> None:
    (drive / "refs.csv").write_text("x,y\n" + "".join(f"{5 * i},0\n" for i in range(PLACES)))
    (drive / "near.csv").write_text("x,y\n" + "".join(f"{5 * i + 1},1\n" for i in range(PLACES)))
    (drive / "far.csv").write_text("x,y\n" + "".join(f"{5 * i},9000\n" for i in range(PLACES)))
    assert invoke("build-map", drive / "refs.npy", "-o", drive / "pm.npz", "--positions", drive / "refs.csv")[0] == 0
    code, _, err = invoke("adapt", drive / "pm.npz", drive / "drive.npy", "--gt-positions", drive / "far.csv",
                          "-o", drive / "a.npz")
    assert code == 2 and "no frame is within 10 m of the map's places: a drive of another route?" in err
    assert not (drive / "a.npz").exists()
    code, _, err = invoke("adapt", drive / "pm.npz", drive / "drive.npy", "--gt-positions", drive / "near.csv",
                          "-o", drive / "a.npz")
    assert code == 0, err
    assert load_map(drive / "a.npz").meta["adapted"]["pairs"] == PLACES


def test_adapting_raises_single_frame_recall_on_places_not_learned_from(drive: Path) -> None:
    half = PLACES // 2
    rows = "\n".join(f"{i},{i}" if i < half else f"{i}," for i in range(PLACES))
    (drive / "first.csv").write_text("query,references\n" + rows + "\n")
    code, _, err = invoke("adapt", drive / "map.npz", drive / "drive.npy", "--gt", drive / "first.csv",
                          "-o", drive / "a.npz")
    assert code == 0, err
    queries = np.load(drive / "drive.npy")[half:]
    plain, adapted = MapQuery(drive / "map.npz"), MapQuery(drive / "a.npz")
    before = np.mean(plain.scores(plain.encode_descriptors(queries))[:, half:].argmax(axis=1) == np.arange(half))
    after = np.mean(adapted.scores(adapted.encode_descriptors(queries))[:, half:].argmax(axis=1) == np.arange(half))
    assert after > before + 0.3, (before, after)


def _bad(w: Path, name: str, text: str) -> Path:
    (w / name).write_text(text)
    return w / name


@pytest.mark.parametrize("args, needle", [
    (lambda w: [w / "short.npy", "--aligned"], "40 frames, but the map has 160 places"),
    (lambda w: [w / "drive.npy", "--gt", _bad(w, "few.csv", "query,references\n" + "".join(
        f"{i},{i}\n" for i in range(30)) + "".join(f"{i},\n" for i in range(30, 160)))], "too short to learn from"),
    (lambda w: [w / "drive.npy", "--gt", _bad(w, "rows.csv", "query,references\n" + "".join(
        f"{i},{i}\n" for i in range(100)))], "100 labelled frames, but"),
    (lambda w: [w / "drive.npy", "--gt", _bad(w, "other.csv", "query,references\n" + "".join(
        f"{i},{i + 500}\n" for i in range(160)))], "names place 659, but the map has 160 places"),
    (lambda w: [w / "drive.npy", "--gt-positions", _bad(w, "pos.csv", "x,y\n1,2\n")],
     "labels by position need a map built with --positions"),
    (lambda w: [w / "drive.npy"], "give the drives' labels one way"),
    (lambda w: [w / "drive.npy", w / "drive.npy", "--gt", w / "drive.csv"], "2 drives but 1 label files"),
])
def test_each_refusal_is_one_line_and_writes_nothing(drive: Path, args, needle: str) -> None:
    code, out, err = invoke("adapt", drive / "map.npz", *args(drive), "-o", drive / "a.npz")
    errors = [line for line in err.splitlines() if line.startswith("vpr-edge: error:")]
    assert code == 2 and len(errors) == 1 and needle in errors[0], err
    assert not (drive / "a.npz").exists()
    assert not [p for p in drive.iterdir() if p.name.startswith(".a.npz")]   # no temporary left


def test_an_adapted_map_is_not_adapted_again_nor_written_over_its_source(drive: Path) -> None:
    assert invoke("adapt", drive / "map.npz", drive / "drive.npy", "--aligned", "-o", drive / "a.npz")[0] == 0
    code, _, err = invoke("adapt", drive / "a.npz", drive / "drive.npy", "--aligned", "-o", drive / "b.npz")
    assert code == 2 and "adapted already (on " in err and not (drive / "b.npz").exists()
    before = (drive / "map.npz").read_bytes()
    code, _, err = invoke("adapt", drive / "map.npz", drive / "drive.npy", "--aligned", "-o", drive / "map.npz")
    assert code == 2 and "would write over an input" in err
    assert (drive / "map.npz").read_bytes() == before


def test_a_map_file_whose_adaptation_does_not_fit_is_refused(drive: Path) -> None:
    assert invoke("adapt", drive / "map.npz", drive / "drive.npy", "--aligned", "-o", drive / "a.npz")[0] == 0
    arrays, meta = read_npz(drive / "a.npz", "map", MAP_SCHEMA)
    write_npz(drive / "cut.npz", {k: v for k, v in arrays.items() if k != "adapt_keep"}, meta)
    code, _, err = invoke("info", drive / "cut.npz")
    assert code == 2 and "adaptation needs adapt_basis, adapt_keep" in err
    write_npz(drive / "wide.npz", arrays | {"adapt_basis": np.zeros((3, DIM + 1), np.float32)}, meta)
    code, _, err = invoke("info", drive / "wide.npz")
    assert code == 2 and "adaptation is inconsistent" in err
    write_npz(drive / "meta.npz", arrays, meta | {"adapted": {"drives": "drive.npy"}})
    code, _, err = invoke("info", drive / "meta.npz")
    assert code == 2 and "'adapted' needs a list of drives" in err


def test_drives_appended_to_an_adapted_map_are_mapped_as_its_own(drive: Path) -> None:
    assert invoke("adapt", drive / "map.npz", drive / "drive.npy", "--aligned", "-o", drive / "a.npz")[0] == 0
    np.save(drive / "more.npy", np.load(drive / "refs.npy")[:20])
    (drive / "b.npz").write_bytes((drive / "a.npz").read_bytes())
    code, _, err = invoke("build-map", drive / "more.npy", "-o", drive / "b.npz", "--append")
    assert code == 0, err
    a, b = load_map(drive / "a.npz"), load_map(drive / "b.npz")
    assert b.adaptation is not None and b.meta["adapted"] == a.meta["adapted"]
    np.testing.assert_allclose(b.stored.dense()[PLACES:], a.stored.dense()[:20], atol=1e-6)


def test_a_codebook_map_without_scipy_is_refused_in_one_line(monkeypatch: pytest.MonkeyPatch) -> None:
    import sys

    from vpr_edge.errors import InputError
    from vpr_edge.map.adapt import require_scipy

    monkeypatch.setitem(sys.modules, "scipy.optimize", None)   # an import of it raises ImportError
    with pytest.raises(InputError, match="map.npz: adapting a codebook map fits its gains with SciPy"):
        require_scipy("map.npz")
