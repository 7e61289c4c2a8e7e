"""Image and frame-source I/O: folders of images in name order, video files, decoding errors."""
from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from vpr_edge.errors import VprError, warn

IMAGE_SUFFIXES = frozenset({".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp", ".ppm", ".pgm"})
VIDEO_SUFFIXES = frozenset({".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg"})
MIN_SIDE = 8  # pixels: below this an image cannot describe a place (a 1x1 "image" is a broken file)


def list_images(folder: str | os.PathLike[str]) -> list[Path]:
    """Image files directly in ``folder``, sorted by name. Raises VprError if missing or empty."""
    folder = Path(folder)
    if not folder.is_dir():
        raise VprError(f"{folder}: not a folder")
    try:
        entries = sorted(p for p in folder.iterdir() if not p.name.startswith(".") and p.is_file())
    except OSError as e:
        raise VprError(f"{folder}: cannot list ({e.strerror or e})") from None
    files = [p for p in entries if p.suffix.lower() in IMAGE_SUFFIXES]
    if not files:
        raise VprError(f"{folder}: no images found (looked for {', '.join(sorted(IMAGE_SUFFIXES))})")
    others = [p.name for p in entries if p.suffix.lower() not in IMAGE_SUFFIXES]
    if others:
        warn(f"{folder}: {len(others)} file(s) that are not images ignored (e.g. {others[0]})")
    return files


def load_image(path: str | os.PathLike[str]) -> np.ndarray:
    """Decode an image file to RGB uint8 (H, W, 3). Raises VprError naming the file if it can't."""
    try:
        data = np.fromfile(str(path), dtype=np.uint8)
    except OSError as e:
        raise VprError(f"{path}: cannot read ({e.strerror or e})") from None
    image = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
    if image is None:
        raise VprError(f"{path}: cannot decode image (corrupt or unsupported format)")
    if min(image.shape[:2]) < MIN_SIDE:
        raise VprError(f"{path}: image is {image.shape[1]}x{image.shape[0]} pixels, too small to describe a "
                       f"place (at least {MIN_SIDE}x{MIN_SIDE})")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


@dataclass(frozen=True)
class Frame:
    """One frame of a stream: its position, a name for reports, and the RGB image or the decode error."""

    index: int
    name: str
    image: np.ndarray | None
    error: str | None = None


def _folder_frames(files: list[Path]) -> Iterator[Frame]:
    for i, f in enumerate(files):
        try:
            yield Frame(i, f.name, load_image(f))
        except VprError as e:
            yield Frame(i, f.name, None, str(e))


def _capture_frames(cap: cv2.VideoCapture, where: str, name: str) -> Iterator[Frame]:
    """Frames from an opened OpenCV capture until it delivers none (end of file, camera stopped)."""
    try:
        i = 0
        while True:
            ok, bgr = cap.read()
            if not ok:
                break
            if min(bgr.shape[:2]) < MIN_SIDE:
                yield Frame(i, f"{name}#{i}", None, f"{where}#{i}: frame is {bgr.shape[1]}x{bgr.shape[0]} "
                                                    f"pixels, too small (at least {MIN_SIDE}x{MIN_SIDE})")
            else:
                yield Frame(i, f"{name}#{i}", cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
            i += 1
    finally:
        cap.release()
    if i == 0:
        raise VprError(f"{where}: no frames could be decoded")


def _video_frames(path: Path) -> Iterator[Frame]:
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise VprError(f"{path}: cannot open video")
    yield from _capture_frames(cap, str(path), path.name)


def _live(source: str) -> tuple[Iterator[Frame], None]:
    """A camera (``0``, ``1``, ... or a device path ``/dev/video0``) or a network stream (``rtsp://...``,
    ``http://...``), opened now so that a wrong source fails before any work."""
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)   # its backend probing warns per backend
    try:
        cap = cv2.VideoCapture(int(source) if source.isdigit() else source)
    finally:
        cv2.utils.logging.setLogLevel(level)
    if not cap.isOpened():
        cap.release()
        kind = "camera" if source.isdigit() or source.startswith("/dev/") else "stream"
        raise VprError(f"{source}: cannot open {kind} (OpenCV found no device or could not connect)")
    name = f"camera{source}" if source.isdigit() else Path(source.split("://")[-1]).name or "stream"
    return _capture_frames(cap, source, name), None


def open_stream(source: str | os.PathLike[str]) -> tuple[Iterator[Frame], int | None]:
    """Frames from a folder of images (name order), a video file, a camera (``0``, ``/dev/video0``) or a
    network stream (``rtsp://``, ``http(s)://``), with the frame count if known (None for live sources).

    Undecodable images come through as frames with ``image=None`` and an ``error`` so that the caller can
    report and skip them; a missing or empty source raises VprError at once.
    """
    text = str(source)
    if text.isdigit() and not Path(text).exists() or text.startswith("/dev/video") or "://" in text:
        return _live(text)
    source = Path(source)
    if source.is_dir():
        files = list_images(source)
        return _folder_frames(files), len(files)
    if source.is_file() and source.suffix.lower() in VIDEO_SUFFIXES:
        cap = cv2.VideoCapture(str(source))
        count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) if cap.isOpened() else 0
        cap.release()
        return _video_frames(source), (count or None)
    if source.is_file():
        raise VprError(f"{source}: not a folder of images nor a video ({', '.join(sorted(VIDEO_SUFFIXES))})")
    raise VprError(f"{source}: no such folder or video file")
