"""Robot recordings: ROS 1 bags (``.bag``), ROS 2 bags (a folder with ``metadata.yaml``, sqlite3 or MCAP) and
MCAP files, read with ``rosbags`` (pure Python, no ROS install; the ``ros`` extra).

Images come from one ``sensor_msgs/Image`` or ``sensor_msgs/CompressedImage`` topic, stamped with their
header's time (a bag's positions: ``positions.bag``, through ``open_reader`` and ``topic_connections``).
"""
from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from vpr_edge.errors import InputError, VprError, warn
from vpr_edge.frames.frame import MIN_SIDE, Frame

IMAGE_TYPES = ("sensor_msgs/msg/CompressedImage", "sensor_msgs/msg/Image")
_CHANNELS = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1, "8UC1": 1, "8UC3": 3}


def is_bag(path: str | os.PathLike[str]) -> bool:
    """A ROS 1 bag or MCAP file (by suffix), or a ROS 2 bag folder (it holds ``metadata.yaml``)."""
    p = Path(path)
    return (p.is_file() and p.suffix.lower() in (".bag", ".mcap")) or (p.is_dir() and (p / "metadata.yaml").is_file())


def open_reader(path: Path):
    """The bag opened with rosbags' ``AnyReader`` (VprError: rosbags missing, or not a readable bag)."""
    try:
        from rosbags.highlevel import AnyReader
    except ImportError:
        raise VprError(f"{path}: reading ROS bags needs rosbags: pip install 'vpr-edge[ros]'") from None
    reader = AnyReader([path])
    try:
        reader.open()
    except Exception as e:   # rosbags raises its own error types per format
        raise VprError(f"{path}: not a readable ROS bag ({str(e).splitlines()[0][:120]})") from None
    return reader


def topic_connections(reader, path: Path, topic: str | None, kinds: tuple[str, ...], given_as: str) -> list:
    """The connections of ``topic``, checked to carry one of ``kinds`` (VprError listing what the bag has;
    ``InputError`` naming the input ``given_as`` when no topic is given)."""
    if not topic:
        have = sorted({c.topic for c in reader.connections if c.msgtype in kinds})
        raise InputError("{path}: a ROS bag needs {opt.%s} TOPIC (its {kinds} topics: {have})" % given_as,
                         path=path, kinds=" / ".join(k.split("/")[-1] for k in kinds), have=", ".join(have) or "none")
    found = [c for c in reader.connections if c.topic == topic]
    if not found:
        topics = sorted({c.topic for c in reader.connections})
        raise VprError(f"{path}: no topic {topic} (it has {', '.join(topics) or 'none'})")
    if found[0].msgtype not in kinds:
        raise VprError(f"{path}: topic {topic} carries {found[0].msgtype}, not "
                       f"{' or '.join(kinds)}")
    return found


def header_stamp(msg, t_ns: int) -> float:
    """A message's header time in seconds, else its recording time ``t_ns`` (nanoseconds)."""
    header = getattr(msg, "header", None)
    if header is not None:
        s = header.stamp
        value = float(s.sec) + float(s.nanosec) * 1e-9
        if value > 0:
            return value
    return t_ns * 1e-9


def _rgb(msg, msgtype: str) -> np.ndarray | str:
    """The message's image as RGB uint8 (H, W, 3), or why it cannot be decoded."""
    import cv2

    if msgtype.endswith("CompressedImage"):
        bgr = cv2.imdecode(np.frombuffer(bytes(msg.data), np.uint8), cv2.IMREAD_COLOR)
        if bgr is None:
            return f"cannot decode its {msg.format or 'compressed'} image"
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    enc, h, w, step = str(msg.encoding), int(msg.height), int(msg.width), int(msg.step)
    channels = _CHANNELS.get(enc)
    if channels is None:
        return f"image encoding {enc!r} is not supported (rgb8, bgr8, rgba8, bgra8, mono8)"
    data = np.frombuffer(bytes(msg.data), np.uint8)
    if step < w * channels or data.size < h * step:
        return f"image data ({data.size} bytes) does not fit {w}x{h} {enc}"
    img = data[: h * step].reshape(h, step)[:, : w * channels].reshape(h, w, channels)
    if channels == 1:
        return cv2.cvtColor(img, cv2.COLOR_GRAY2RGB)
    if enc in ("bgr8", "8UC3"):
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    if enc == "bgra8":
        return cv2.cvtColor(img, cv2.COLOR_BGRA2RGB)
    return np.ascontiguousarray(img[:, :, :3])


def open_bag(path: str | os.PathLike[str], topic: str | None) -> tuple[Iterator[Frame], int]:
    """The image frames of ``topic`` in the bag, in time order, each named ``BAG#N`` and stamped with its
    header's time (seconds); checked before any frame is read (VprError: no such topic, another type)."""
    path = Path(path)
    reader = open_reader(path)
    try:
        conns = topic_connections(reader, path, topic, IMAGE_TYPES, "topic")
    except BaseException:
        reader.close()
        raise
    count = sum(c.msgcount for c in conns)

    def frames() -> Iterator[Frame]:
        try:
            for i, (conn, t_ns, raw) in enumerate(reader.messages(connections=conns)):
                name = f"{path.name}#{i}"
                try:
                    msg = reader.deserialize(raw, conn.msgtype)
                except Exception as e:    # a damaged message: reported and skipped like a bad frame
                    yield Frame(i, name, None, f"{path}#{i}: cannot deserialize ({str(e)[:80]})", t_ns * 1e-9)
                    continue
                stamp = header_stamp(msg, t_ns)
                rgb = _rgb(msg, conn.msgtype)
                if isinstance(rgb, str):
                    yield Frame(i, name, None, f"{path}#{i}: {rgb}", stamp)
                elif min(rgb.shape[:2]) < MIN_SIDE:
                    yield Frame(i, name, None, f"{path}#{i}: frame is {rgb.shape[1]}x{rgb.shape[0]} pixels, "
                                               f"too small", stamp)
                else:
                    yield Frame(i, name, rgb, stamp=stamp)
        finally:
            reader.close()

    if count == 0:
        reader.close()
        raise VprError(f"{path}: topic {topic} holds no messages")
    return frames(), count


def extract_images(path: str | os.PathLike[str], topic: str | None, folder: Path
                   ) -> tuple[list[Path], list[str], np.ndarray]:
    """The image topic's frames written to ``folder`` as ``NNNNNN.png`` (lossless; so that build-map reads
    them as it reads any folder) -> (files, names ``BAG#N``, stamps (N,) seconds). Undecodable messages are
    skipped with a warning; none decodable is a VprError."""
    import cv2

    frames, _ = open_bag(path, topic)
    files, names, stamps = [], [], []
    for frame in frames:
        if frame.image is None:
            warn(f"{frame.error}; skipped")
            continue
        f = folder / f"{len(files):06d}.png"
        if not cv2.imwrite(str(f), cv2.cvtColor(frame.image, cv2.COLOR_RGB2BGR)):
            raise VprError(f"{f}: cannot write a frame extracted from {path}")
        files.append(f)
        names.append(frame.name)
        stamps.append(frame.stamp)
    if not files:
        raise VprError(f"{path}: none of the images on {topic} could be decoded")
    return files, names, np.asarray(stamps, np.float64)
