"""The test streams a vehicle produces, derived from a frame-aligned pair (``vpr_edge_bench.streams``), and the
folder of them every experiment reads (``vpr_edge_bench.folder.StreamsFolder``)."""
from __future__ import annotations

import numpy as np
import pytest

from vpr_edge.errors import VprError
from vpr_edge_bench.folder import StreamsFolder, streams_folders
from vpr_edge_bench.streams import (CAMERA, KINDS, Exposure, derive_stream, new_exposure, sensor_noise,
                                    write_stream)


@pytest.mark.parametrize("kind", KINDS)
def test_derived_streams(kind: str) -> None:
    places = derive_stream(kind, 300, 450, seed=1)
    mapped = places[places < 300]
    assert len(places) > 50 and places.min() >= 0 and places.max() < 450
    steps = np.diff(mapped)
    if kind == "detour":
        assert (places >= 300).sum() == 90 and places[-1] == 299
    else:
        assert (places < 300).all()
    if kind == "speed3":
        assert set(steps) == {3}
    if kind == "stop-and-go":
        assert (steps == 0).sum() > 20 and set(steps) <= {0, 1}
    if kind == "variable":
        assert 0 <= steps.min() and steps.max() <= 3 and len(set(steps)) >= 3


def test_sensor_noise_matches_its_sigma_and_stays_in_range() -> None:
    rng = np.random.default_rng(0)
    image = np.full((200, 100, 3), 128, np.uint8)
    noisy = sensor_noise(image, 3.0, rng)
    assert noisy.dtype == np.uint8 and noisy.shape == image.shape
    assert abs(float((noisy.astype(float) - 128).std()) - 3.0) < 0.1
    edges = sensor_noise(np.tile(np.array([[0, 255]], np.uint8), (500, 1)), 50.0, rng).astype(int)
    dark, bright = edges[:, 0], edges[:, 1]
    assert 0.4 < np.mean(dark == 0) < 0.6 and 0.4 < np.mean(bright == 255) < 0.6   # clipped at the ends ...
    assert dark.max() < 200 and bright.min() > 55                                   # ... not wrapped around


def test_write_stream_repeats_are_noisy_copies(tmp_path, small_queries) -> None:
    import cv2

    sources = sorted(small_queries.iterdir())[:3]
    places = np.array([0, 1, 1, 1, 2])
    write_stream(tmp_path / "s", sources, places, n_mapped=2, repeat_noise=3.0, seed=1)
    names = sorted(p.name for p in (tmp_path / "s").iterdir())
    assert names == ["0000000.jpg", "0000001.jpg", "0000002.png", "0000003.png", "0000004.jpg"]
    assert (tmp_path / "s.csv").read_text().splitlines()[1:] == ["0,0", "1,1", "2,1", "3,1", "4,"]
    base = cv2.imread(str(sources[1]), cv2.IMREAD_UNCHANGED).astype(float)
    a, b = (cv2.imread(str(tmp_path / "s" / n), cv2.IMREAD_UNCHANGED).astype(float) for n in names[2:4])
    assert a.shape == base.shape and 2.0 < (a - base).std() < 4.0 and not np.array_equal(a, b)
    write_stream(tmp_path / "t", sources, places, n_mapped=2)             # default: the same file again
    assert sorted(p.name for p in (tmp_path / "t").iterdir())[2:4] == ["0000002.jpg", "0000003.jpg"]


def test_camera_stops_are_stop_and_go_with_new_exposures(tmp_path, small_queries) -> None:
    """camera-stops stops where stop-and-go does (same seed); each repeat is a new exposure: the place's image
    shifted by a fraction of a pixel, its gain changed and noise added, so close to it but never equal, and
    no two repeats alike."""
    import cv2

    for seed in (0, 3):
        np.testing.assert_array_equal(derive_stream("camera-stops", 50, 60, seed),
                                      derive_stream("stop-and-go", 50, 60, seed))
    image = (np.arange(40 * 60 * 3) % 251).astype(np.uint8).reshape(40, 60, 3)
    still = new_exposure(image, Exposure(noise=0.0, gain=0.0, shift=0.0), np.random.default_rng(0))
    np.testing.assert_array_equal(still, image)                           # no noise, gain nor shift: the image
    sources = sorted(small_queries.iterdir())[:3]
    places = np.array([0, 1, 1, 1, 2])
    write_stream(tmp_path / "s", sources, places, n_mapped=3, seed=1, exposure=CAMERA)
    names = sorted(p.name for p in (tmp_path / "s").iterdir())
    assert names == ["0000000.jpg", "0000001.jpg", "0000002.png", "0000003.png", "0000004.jpg"]
    base = cv2.imread(str(sources[1])).astype(float)
    a, b = (cv2.imread(str(tmp_path / "s" / n)).astype(float) for n in names[2:4])
    assert a.shape == base.shape and 1.0 < np.abs(a - base).mean() < 8.0 and not np.array_equal(a, b)


def test_a_streams_folder_is_checked_before_any_work(tmp_path) -> None:
    """``check`` names the first thing a derived-streams folder lacks (its map, ref/, a stream or its truth) and
    how to make one; a complete folder passes, with or without asking for its map."""
    folder = tmp_path / "corridor"
    with pytest.raises(VprError, match=r"corridor: not a derived-streams folder with its map \(no map.npz; make "
                                       r"one: python -m vpr_edge_bench derive-streams"):
        StreamsFolder(folder).check()
    with pytest.raises(VprError, match=r"not a derived-streams folder \(no ref;"):
        StreamsFolder(folder).check(map=False, ref=True)
    (folder / "ref").mkdir(parents=True)
    for kind in KINDS:
        (folder / kind).mkdir()
        (folder / f"{kind}.csv").write_text("query,references\n")
    (folder / "detour.csv").unlink()
    with pytest.raises(VprError, match=r"\(no detour.csv;"):
        StreamsFolder(folder).check(map=False)
    assert StreamsFolder(folder, ["aligned"]).check(map=False).kinds == ("aligned",)
    (folder / "detour.csv").write_text("query,references\n")
    (folder / "map.npz").write_bytes(b"")
    f = StreamsFolder(folder).check(ref=True)
    assert (f.name, f.map, f.ref, f.frames("speed2"), f.truth("speed2")) == (
        "corridor", folder / "map.npz", folder / "ref", folder / "speed2", folder / "speed2.csv")
    assert [x.name for x in streams_folders([folder])] == ["corridor"]


def test_streams_folders_need_distinct_names_before_anything_else(tmp_path) -> None:
    """The folders' names name the datasets in tables and outputs: two alike are refused first, even where the
    folders are not there."""
    with pytest.raises(VprError, match="names name the datasets and must differ: a, a"):
        streams_folders([tmp_path / "x" / "a", tmp_path / "y" / "a"], distinct=True)
    with pytest.raises(VprError, match="no map.npz"):
        streams_folders([tmp_path / "x" / "a", tmp_path / "y" / "a"])
