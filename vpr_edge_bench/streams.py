"""Query streams a vehicle produces, derived from a frame-aligned reference/query pair, with ground truth.

The shared datasets line up query frame i with reference place i, so "reference = frame index" is perfect on
them. These functions derive other streams from such a pair: the map holds places [0, n_mapped) and the
query frames of places [n_mapped, n_places) serve as unmapped places for detours. Each derived stream is a
list of source query indices (which frame to show) and, per frame, its true place (-1 = not in the map).
"""
from __future__ import annotations

import os
import shutil
from collections.abc import Sequence
from pathlib import Path

from dataclasses import dataclass

import numpy as np

from vpr_edge.errors import VprError
from vpr_edge.frames.images import list_images, load_image
from vpr_edge.evaluation.truth import write_ground_truth
from vpr_edge.files.atomic import atomic_output
from vpr_edge.files.readers import read_csv_rows

KINDS: tuple[str, ...] = ("aligned", "speed2", "speed3", "stop-and-go", "camera-stops", "variable", "partial",
                          "detour")


@dataclass(frozen=True)
class Exposure:
    """How a real camera's frame of a place it already showed differs from the last one: a new exposure, not
    the same pixels. ``noise``: sigma of Gaussian sensor noise (grey levels); ``gain``: the exposure's gain
    drawn uniformly within 1 +- gain; ``shift``: sub-pixel vibration, a translation drawn uniformly within
    +- shift pixels on each axis (of the source image)."""

    noise: float = 2.0
    gain: float = 0.02
    shift: float = 0.3


CAMERA = Exposure()   # the camera-stops kind's exposures


def derive_stream(kind: str, n_mapped: int, n_places: int, seed: int = 0) -> np.ndarray:
    """Source place index per frame of the derived stream (F,) int; values >= n_mapped are unmapped places.

    aligned: 1 place/frame over the map; speed2/speed3: every 2nd/3rd place; stop-and-go: runs at 1
    place/frame broken by stops of 5-20 repeated frames; camera-stops: the same places as stop-and-go (same
    seed), written as a real camera shows a stop (each repeat a new exposure: ``write_stream``'s
    ``exposure``); variable: speed drifting smoothly in [0.5, 3]
    places/frame; partial: the middle half of the map; detour: the first 40% of the map, then up to 30%
    of n_mapped frames of unmapped places, then re-entering at 60% of the map to its end.
    """
    rng = np.random.default_rng(seed)
    if kind == "aligned":
        return np.arange(n_mapped)
    if kind in ("speed2", "speed3"):
        return np.arange(0, n_mapped, int(kind[-1]))
    if kind in ("stop-and-go", "camera-stops"):
        out: list[int] = []
        place = 0
        while place < n_mapped:
            run = int(rng.integers(10, 31))
            out.extend(range(place, min(place + run, n_mapped)))
            place += run
            if place < n_mapped:
                out.extend([place - 1] * int(rng.integers(5, 21)))
        return np.array(out)
    if kind == "variable":
        pos, speed, out = 0.0, 1.0, []
        while pos < n_mapped:
            out.append(int(pos))
            speed = float(np.clip(speed + rng.normal(0, 0.25), 0.5, 3.0))
            pos += speed
        return np.array(out)
    if kind == "partial":
        return np.arange(n_mapped // 4, (3 * n_mapped) // 4)
    if kind == "detour":
        n_off = min(n_places - n_mapped, max(1, (3 * n_mapped) // 10))
        if n_places <= n_mapped:
            raise VprError("a detour needs places outside the map (n_mapped < number of places)")
        return np.concatenate([np.arange(0, (2 * n_mapped) // 5), np.arange(n_mapped, n_mapped + n_off),
                               np.arange((3 * n_mapped) // 5, n_mapped)])
    raise VprError(f"unknown stream kind {kind!r}; choose from {', '.join(KINDS)}")


def sensor_noise(image: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """``image`` (H, W[, C]) uint8 plus Gaussian noise of ``sigma`` grey levels per pixel, rounded and clipped:
    a camera's frame-to-frame noise, so that a stopped vehicle's frames are alike but not identical."""
    noisy = image.astype(np.float32) + rng.normal(0.0, sigma, image.shape).astype(np.float32)
    return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)


def new_exposure(image: np.ndarray, exposure: Exposure, rng: np.random.Generator) -> np.ndarray:
    """``image`` (H, W, 3) uint8 as the camera's next frame of the same view: shifted by a sub-pixel
    translation (bilinear, borders reflected), scaled by a gain, plus sensor noise (``Exposure``)."""
    import cv2

    dx, dy = rng.uniform(-exposure.shift, exposure.shift, 2)
    shifted = cv2.warpAffine(image.astype(np.float32), np.float32([[1, 0, dx], [0, 1, dy]]),
                             (image.shape[1], image.shape[0]), flags=cv2.INTER_LINEAR,
                             borderMode=cv2.BORDER_REFLECT)
    gained = np.clip(np.rint(shifted * rng.uniform(1 - exposure.gain, 1 + exposure.gain)), 0, 255)
    return sensor_noise(gained.astype(np.uint8), exposure.noise, rng) if exposure.noise > 0 else \
        gained.astype(np.uint8)


def write_stream(out: str | os.PathLike[str], sources: Sequence[Path], places: np.ndarray, n_mapped: int,
                 with_truth: bool = True, repeat_noise: float = 0.0, seed: int = 0,
                 exposure: Exposure | None = None) -> None:
    """Write frames ``sources[places[i]]`` as ``out/NNNNNNN.ext`` (hard links where possible) and, with
    ``with_truth``, ``out.csv``: their ground truth (the true place, or empty for an unmapped one).
    A frame showing the same place as the one before it (a stop, a slow crawl) is written as a new PNG
    instead of as the same file again (seeded): with ``exposure``, a camera's new exposure of the place
    (``new_exposure``), else with ``repeat_noise`` > 0 ``sensor_noise`` of that sigma."""
    import cv2

    out = Path(out)
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    rng = np.random.default_rng(seed)
    for i, p in enumerate(places):
        src = sources[int(p)]
        if (exposure is not None or repeat_noise > 0) and i > 0 and p == places[i - 1]:
            image = load_image(src)
            noisy = new_exposure(image, exposure, rng) if exposure is not None else \
                sensor_noise(image, repeat_noise, rng)
            ok, png = cv2.imencode(".png", cv2.cvtColor(noisy, cv2.COLOR_RGB2BGR))
            if not ok:
                raise VprError(f"{src}: cannot be encoded as PNG")
            with atomic_output(out / f"{i:07d}.png") as tmp:
                tmp.write_bytes(png.tobytes())
            continue
        dst = out / f"{i:07d}{src.suffix}"
        try:
            os.link(src, dst)
        except OSError:
            shutil.copyfile(src, dst)
    if with_truth:
        write_ground_truth(out.with_suffix(".csv"), [[int(p)] if p < n_mapped else [] for p in places])


def derive_streams(dataset: str | os.PathLike[str], out: str | os.PathLike[str], kinds: Sequence[str] = KINDS,
                   map_places: int | None = None, seed: int = 0, repeat_noise: float = 0.0,
                   drives: int = 0) -> dict[str, int]:
    """The ``derive-streams`` experiment: from a frame-aligned pair (``dataset``/ref, ``dataset``/query) write
    ``out``/ref (the map's first ``map_places`` places; default two thirds) and per kind ``out``/KIND with
    ``out``/KIND.csv (``derive_stream``, ``write_stream``; camera-stops with ``CAMERA`` exposures). Inputs are
    checked first (VprError). With ``drives`` the map is also cut into that many drives (``cut_into_drives``,
    seeded). Returns frames per kind and, under "map places", the map's size."""
    dataset, out = Path(dataset), Path(out)
    refs, queries = list_images(dataset / "ref"), list_images(dataset / "query")
    if len(refs) != len(queries):
        raise VprError(f"{dataset}: ref/ and query/ differ in length ({len(refs)} vs {len(queries)})")
    n_mapped = map_places or (2 * len(refs)) // 3
    if not 0 < n_mapped <= len(refs):
        raise VprError(f"--map-places must be in 1..{len(refs)}")
    unknown = [k for k in kinds if k not in KINDS]
    if unknown:
        raise VprError(f"--kinds: unknown {', '.join(unknown)}; choose from {', '.join(KINDS)}")
    if repeat_noise < 0:
        raise VprError(f"--repeat-noise must be >= 0, got {repeat_noise}")
    if drives and not 1 <= drives <= n_mapped:
        raise VprError(f"--drives must be in 1..{n_mapped}, got {drives}")
    write_stream(out / "ref", refs, np.arange(n_mapped), n_mapped, with_truth=False)
    counts = {}
    for kind in kinds:
        places = derive_stream(kind, n_mapped, len(refs), seed)
        write_stream(out / kind, queries, places, n_mapped, repeat_noise=repeat_noise, seed=seed,
                     exposure=CAMERA if kind == "camera-stops" else None)
        counts[kind] = len(places)
    if drives:
        cut_into_drives(out, drives, seed)
    return counts | {"map places": n_mapped}


DRIVES_FOLDER = "drives"   # derive-streams --drives: the map cut into drives, under OUT/drives/


def cut_into_drives(out: str | os.PathLike[str], n_drives: int, seed: int = 0) -> list[str]:
    """A multi-drive version of a derived dataset: ``out``/ref (the map's places in route order) cut into
    ``n_drives`` drives of consecutive places, ``out``/drives/0, 1, ... whose frames are named alike in every
    drive (``frame_0000.jpg`` ...: every camera names its frames so), and per stream kind with ground truth
    ``out``/drives/KIND.csv naming the true place as ``DRIVE/NAME``. Returns the drives' folders in a shuffled
    order (seeded), the order a fleet's drives come in."""
    out = Path(out)
    refs = list_images(out / "ref")
    if not 1 <= n_drives <= len(refs):
        raise VprError(f"--drives must be in 1..{len(refs)}, got {n_drives}")
    root = out / DRIVES_FOLDER
    if root.exists():
        shutil.rmtree(root)
    bounds = np.linspace(0, len(refs), n_drives + 1).round().astype(int)
    label = {}
    for k in range(n_drives):
        (root / str(k)).mkdir(parents=True)
        for i, place in enumerate(range(bounds[k], bounds[k + 1])):
            name = f"frame_{i:04d}{refs[place].suffix}"
            try:
                os.link(refs[place], root / str(k) / name)
            except OSError:
                shutil.copyfile(refs[place], root / str(k) / name)
            label[place] = f"{k}/{name}"
    for truth in [out / f"{kind}.csv" for kind in KINDS if (out / f"{kind}.csv").is_file()]:
        rows = read_csv_rows(truth, "ground truth")
        lines = ["query,references"] + [f"{row[0]}," + " ".join(label[int(v)] for v in (row[1].split() if len(row) > 1
                                                                                          else []))
                                        for _, row in rows[1:]]
        with atomic_output(root / truth.name) as tmp:
            tmp.write_text("\n".join(lines) + "\n")
    return drive_order(out, n_drives, seed)


def drive_order(out: str | os.PathLike[str], n_drives: int, seed: int = 0) -> list[str]:
    """The folders of ``cut_into_drives``' drives in the shuffled order (seeded) they are given in."""
    return [str(Path(out) / DRIVES_FOLDER / str(k)) for k in np.random.default_rng(seed).permutation(n_drives)]
