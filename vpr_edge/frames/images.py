"""Image and frame-source I/O: folders of images in name order, video files, decoding errors, and the
frames that match less well, said (a drive's frames of mixed sizes, greyscale frames)."""
from __future__ import annotations

import os
import time
from collections import Counter
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path

import cv2
import numpy as np

from vpr_edge.errors import InputError, VprError, warn
from vpr_edge.frames.frame import MIN_SIDE, Frame
from vpr_edge.frames.headers import image_size

IMAGE_SUFFIXES = frozenset({".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp", ".ppm", ".pgm"})
VIDEO_SUFFIXES = frozenset({".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg"})


def list_images(folder: str | os.PathLike[str]) -> list[Path]:
    """Image files directly in ``folder``, sorted by name. Raises VprError if missing or empty. A link named
    as an image is listed even when it leads nowhere (its target gone, or a loop): it holds a frame's place,
    so the frames after it keep their numbers, and reading it fails as a broken file's does (a stream skips
    it with a warning naming it; a map's references refuse it)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise VprError(f"{folder}: not a folder")
    try:
        entries = sorted(p for p in folder.iterdir()
                         if not p.name.startswith(".") and (p.is_symlink() or p.is_file()))
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


def check_frame_sizes(where: str | os.PathLike[str], files: Sequence[Path], strict: bool = False,
                      names: Sequence[str] | None = None, resized_to: str = "the model's input") -> None:
    """Frames of more than one size among ``files`` (one drive, ``where``), read from their headers
    (``frames.headers``; a header that cannot be read is left to the decoder): one warning naming the sizes,
    how many frames have each and the first file of another size than most (``names``: how to name the
    files, if not by their paths); with ``strict`` an ``InputError`` instead."""
    sizes = [image_size(f) for f in files]
    counts = Counter(s for s in sizes if s is not None)
    if len(counts) < 2:
        return
    first = next(s for s in sizes if s is not None)
    most = max(counts, key=lambda s: (counts[s], s == first))   # a tie: the first frame's size
    odd = [i for i, s in enumerate(sizes) if s is not None and s != most]
    others = sorted((s for s in counts if s != most), key=lambda s: (-counts[s], sizes.index(s)))
    text = "{}x{}".format
    example = names[odd[0]] if names is not None else str(files[odd[0]])
    total = sum(counts.values())
    if len(others) == 1:
        line = f"{where}: {len(odd)} of {total} frames are {text(*others[0])}, the rest {text(*most)} (e.g. {example})"
    else:
        listed = ", ".join(f"{text(*s)} ({counts[s]})" for s in others)
        line = (f"{where}: {len(odd)} of {total} frames are of {len(others)} other sizes, {listed}, the rest "
                f"{text(*most)} (e.g. {example})")
    if strict:
        raise InputError("{line}; {opt.strict} refuses frames of mixed sizes", line=line)
    warn(f"{line}; they are resized to {resized_to}, which matches less well")


GREY_GRID = 32        # a frame is judged greyscale on a grid of at most GREY_GRID x GREY_GRID of its pixels
GREY_TOLERANCE = 2    # channels within this of each other are equal (a codec's rounding)
GREY_FLAT = 16        # grid pixels within this of each other: a frame of one shade (black, blown out), not judged


def is_greyscale(image: np.ndarray) -> bool:
    """Whether ``image`` is greyscale: one channel, or three equal on a grid of its pixels (cheap: at most
    ``GREY_GRID`` squared). A frame of one shade (a black or blown-out frame of a colour camera) is not."""
    if image.ndim == 2 or image.shape[2] == 1:
        return True
    h, w = image.shape[:2]
    grid = image[::max(1, h // GREY_GRID), ::max(1, w // GREY_GRID), :3].astype(np.int16)
    if int(grid.max()) - int(grid.min()) <= GREY_FLAT:
        return False
    return bool(np.abs(grid[..., 0] - grid[..., 1]).max() <= GREY_TOLERANCE
                and np.abs(grid[..., 1] - grid[..., 2]).max() <= GREY_TOLERANCE)


class GreyFrames:
    """One command's watch for greyscale frames given to a front end that takes colour (``colour``: its
    channel order, e.g. RGB; None: it reads grey itself, and nothing is checked): the first one seen is said
    in one warning naming it, the others are not looked at."""

    def __init__(self, colour: str | None, model: str = "the model") -> None:
        self.colour, self.model = colour, model
        self.found: str | None = None

    @classmethod
    def of(cls, front: object) -> "GreyFrames":
        """The watch for a front end: its ``colour`` (the cnn front end's; handcrafted ones read grey)."""
        colour = getattr(front, "colour", None)
        path = getattr(front, "path", None)
        return cls(colour, f"the model {Path(path).name}" if path is not None else "the model")

    def see(self, image: np.ndarray, where: str | os.PathLike[str]) -> None:
        """Look at one frame (``where``: how to name it), until one is found greyscale."""
        if self.colour is None or self.found is not None or not is_greyscale(image):
            return
        self.found = str(where)
        warn(f"{where}: greyscale frame, but {self.model} expects colour ({self.colour}); greyscale frames "
             f"match less well than colour ones")

    def watch(self, frames: Iterable[Frame], folder: str | os.PathLike[str] | None = None) -> Iterator[Frame]:
        """``frames`` as they are, each looked at (``see``) until one is found; a frame is named by its path
        in ``folder`` if given, else by its name."""
        try:
            for frame in frames:
                if frame.image is not None and self.found is None:
                    self.see(frame.image, Path(folder) / frame.name if folder is not None else frame.name)
                yield frame
        finally:
            close = getattr(frames, "close", None)
            if close is not None:
                close()


def _folder_frames(files: list[Path], stamps: list[float] | None = None) -> Iterator[Frame]:
    for i, f in enumerate(files):
        stamp = stamps[i] if stamps is not None else None
        try:
            yield Frame(i, f.name, load_image(f), stamp=stamp)
        except VprError as e:
            yield Frame(i, f.name, None, str(e), stamp)


def read_stamps(path: str | os.PathLike[str], names: list[str]) -> list[float]:
    """Each frame's time in seconds from a CSV with a header ``frame,stamp`` (``name`` for ``frame`` too),
    one row per image of the folder; VprError naming the file for a missing frame or a bad number."""
    import math

    from vpr_edge.files.readers import read_csv_rows

    path = Path(path)
    rows = read_csv_rows(path, "timestamps")
    head = [c.strip().lower() for c in rows[0][1]] if rows else []
    key = next((c for c in ("frame", "name") if c in head), None)
    if key is None or "stamp" not in head:
        raise VprError(f"{path}: timestamps need the header frame,stamp (seconds)")
    k, s = head.index(key), head.index("stamp")
    found: dict[str, float] = {}
    for line, row in rows[1:]:
        if not any(cell.strip() for cell in row):
            continue
        try:
            found[row[k].strip()] = value = float(row[s])
        except (ValueError, IndexError):
            raise VprError(f"{path}: line {line}: a frame name and a stamp in seconds expected") from None
        if not math.isfinite(value):
            raise VprError(f"{path}: line {line}: stamp is not finite")
    missing = [n for n in names if n not in found]
    if missing:
        raise VprError(f"{path}: no stamp for {len(missing)} frame(s) of the folder (e.g. {missing[0]})")
    return [found[n] for n in names]


def _capture_frames(cap: cv2.VideoCapture, where: str, name: str, live: bool = False) -> Iterator[Frame]:
    """Frames from an opened OpenCV capture until it delivers none (end of file, camera stopped), stamped
    with the video's presentation time, or for a ``live`` source the time each frame arrived."""
    try:
        i = 0
        while True:
            ok, bgr = cap.read()
            if not ok:
                break
            stamp = time.time() if live else cap.get(cv2.CAP_PROP_POS_MSEC) / 1000.0
            if min(bgr.shape[:2]) < MIN_SIDE:
                yield Frame(i, f"{name}#{i}", None, f"{where}#{i}: frame is {bgr.shape[1]}x{bgr.shape[0]} "
                                                    f"pixels, too small (at least {MIN_SIDE}x{MIN_SIDE})", stamp)
            else:
                yield Frame(i, f"{name}#{i}", cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), stamp=stamp)
            i += 1
    finally:
        cap.release()
    if i == 0:
        raise VprError(f"{where}: no frames could be decoded")


def _video(path: Path) -> tuple[Iterator[Frame], int | None]:
    """A video file's frames and their count if it says, opened now so that a file OpenCV cannot open fails
    before any work (and before any output)."""
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        cap.release()
        raise VprError(f"{path}: cannot open video (not a video OpenCV can decode, or damaged)")
    count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    return _capture_frames(cap, str(path), path.name), (count if count > 0 else None)


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
    return _capture_frames(cap, source, name, live=True), None


def open_stream(source: str | os.PathLike[str], stamps: str | os.PathLike[str] | None = None,
                topic: str | None = None) -> tuple[Iterator[Frame], int | None]:
    """Frames from a folder of images (name order), a video file, a camera (``0``, ``/dev/video0``), a
    network stream (``rtsp://``, ``http(s)://``), a ROS bag / MCAP file (the image ``topic``; ``bags``) or a
    file of global descriptors (``.npy``, ``.h5``: ``descriptors``), with the frame count if known (None for
    live sources).

    Undecodable images come through as frames with ``image=None`` and an ``error`` so that the caller can
    report and skip them; a missing or empty source raises VprError at once.
    """
    text = str(source)
    from vpr_edge.frames.bags import is_bag, open_bag
    from vpr_edge.frames.descriptor_files import descriptor_frames, is_descriptor_file

    if is_descriptor_file(text):
        if stamps or topic:
            raise InputError("{text}: {opt.timestamps} and {opt.topic} apply to images; a descriptor file is frames "
                             "in order", text=text)
        return descriptor_frames(text)
    if is_bag(text):
        if stamps:
            raise InputError("{stamps}: {opt.timestamps} applies to a folder of frames; {text} stamps its own frames",
                             stamps=stamps, text=text)
        return open_bag(text, topic)
    if topic:
        raise InputError("{text}: {opt.topic} applies to a ROS bag or MCAP file, not to this source", text=text)
    if text.isdigit() and not Path(text).exists() or text.startswith("/dev/video") or "://" in text:
        if stamps:
            raise InputError("{stamps}: {opt.timestamps} applies to a folder of frames; {text} is stamped as it "
                             "arrives", stamps=stamps, text=text)
        return _live(text)
    source = Path(source)
    if source.is_dir():
        files = list_images(source)
        return _folder_frames(files, read_stamps(stamps, [f.name for f in files]) if stamps else None), len(files)
    if stamps:
        raise InputError("{stamps}: {opt.timestamps} applies to a folder of frames; {source} stamps its own frames",
                         stamps=stamps, source=source)
    if source.is_file() and source.suffix.lower() in VIDEO_SUFFIXES:
        return _video(source)
    if source.is_file():
        raise VprError(f"{source}: not a folder of images nor a video ({', '.join(sorted(VIDEO_SUFFIXES))})")
    raise VprError(f"{source}: no such folder or video file")
