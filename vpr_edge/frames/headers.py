"""An image file's size in pixels read from its header, without decoding it: JPEG, PNG, BMP, TIFF, WebP and
the PNM family (PPM, PGM). The EXIF orientation of a JPEG, PNG, WebP or TIFF is applied, as OpenCV applies
it when decoding, so the size is the decoded image's. ``image_size`` returns None for a header it cannot read; the
decoder then says what is wrong with the file."""
from __future__ import annotations

import os
import struct
from typing import BinaryIO

_JPEG_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}   # start-of-frame markers (not DHT, JPG, DAC)
_MAX_SEGMENTS = 64   # JPEG segments, PNG or WebP chunks walked, at most (EXIF, ICC, ... come before the pixels)


def image_size(path: str | os.PathLike[str]) -> tuple[int, int] | None:
    """``path``'s (width, height) in pixels as decoded (EXIF orientation applied), from its header; None when
    the header cannot be read or the format is not one of those above."""
    size = _header_size(path)
    return size if size is not None and min(size) > 0 else None


def _header_size(path: str | os.PathLike[str]) -> tuple[int, int] | None:
    try:
        with open(path, "rb") as f:
            head = f.read(32)
            if head[:2] == b"\xff\xd8":
                f.seek(2)
                return _jpeg(f)
            if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
                f.seek(8)
                return _png(f)
            if head[:2] == b"BM" and len(head) >= 26:
                return _bmp(head)
            if head[:4] in (b"II*\x00", b"MM\x00*"):
                f.seek(0)
                return _tiff(f.read(1 << 16))
            if head[:4] == b"RIFF" and head[8:12] == b"WEBP":
                f.seek(12)
                return _webp(f)
            if head[:1] == b"P" and len(head) > 2 and head[1] in b"123456":
                return _pnm(head + f.read(256))
    except (OSError, struct.error, ValueError, IndexError):
        return None
    return None


def _jpeg(f: BinaryIO) -> tuple[int, int] | None:
    """After the SOI marker: the frame header's size, turned as an APP1 EXIF orientation says."""
    turned = False
    for _ in range(_MAX_SEGMENTS):
        marker = f.read(2)
        while marker[:1] == b"\xff" and marker[1:2] == b"\xff":   # fill bytes before a marker
            marker = marker[1:] + f.read(1)
        if len(marker) < 2 or marker[0] != 0xFF:
            return None
        kind = marker[1]
        if kind in (0x01, *range(0xD0, 0xD8)):   # markers without a length
            continue
        (length,) = struct.unpack(">H", f.read(2))
        if length < 2:
            return None
        body = f.read(length - 2)
        if kind in _JPEG_SOF:
            height, width = struct.unpack(">HH", body[1:5])
            return (height, width) if turned else (width, height)
        if kind == 0xE1 and body[:6] == b"Exif\x00\x00":
            turned = _turned(body[6:])
        if kind in (0xD9, 0xDA):   # end of image, start of scan: no frame header before them
            return None
    return None


def _ifd0(data: bytes) -> dict[int, int]:
    """A TIFF structure's first directory: tag -> value, for the SHORT and LONG tags."""
    order = "<" if data[:2] == b"II" else ">"
    (at,) = struct.unpack(order + "I", data[4:8])
    (count,) = struct.unpack(order + "H", data[at:at + 2])
    tags = {}
    for i in range(count):
        entry = data[at + 2 + 12 * i: at + 14 + 12 * i]
        tag, kind = struct.unpack(order + "HH", entry[:4])
        if kind == 3:
            tags[tag] = struct.unpack(order + "H", entry[8:10])[0]
        elif kind == 4:
            tags[tag] = struct.unpack(order + "I", entry[8:12])[0]
    return tags


def _turned(tiff: bytes) -> bool:
    """Whether an EXIF block's orientation (5 to 8) turns the image a quarter, swapping its sides."""
    try:
        return _ifd0(tiff).get(0x0112, 1) in (5, 6, 7, 8)
    except (struct.error, ValueError, IndexError):
        return False


def _tiff(data: bytes) -> tuple[int, int] | None:
    """A TIFF file's first image: its width and length tags, turned as its orientation tag says."""
    tags = _ifd0(data)
    if 256 not in tags or 257 not in tags:
        return None
    width, height = tags[256], tags[257]
    return (height, width) if tags.get(0x0112, 1) in (5, 6, 7, 8) else (width, height)


def _bmp(head: bytes) -> tuple[int, int]:
    (header,) = struct.unpack("<I", head[14:18])
    if header == 12:   # OS/2 BITMAPCOREHEADER: 16-bit sides
        return struct.unpack("<HH", head[18:22])
    width, height = struct.unpack("<ii", head[18:26])
    return abs(width), abs(height)   # a negative height: rows stored top-down


def _png(f: BinaryIO) -> tuple[int, int] | None:
    """After the signature: IHDR's size, turned as an eXIf chunk before the pixels says."""
    size = None
    for _ in range(_MAX_SEGMENTS):
        length, kind = struct.unpack(">I4s", f.read(8))
        if kind in (b"IDAT", b"IEND"):
            break
        if kind not in (b"IHDR", b"eXIf"):
            f.seek(length + 4, os.SEEK_CUR)   # the chunk and its CRC
            continue
        body = f.read(min(length, 1 << 16))
        f.seek(length - len(body) + 4, os.SEEK_CUR)
        if kind == b"IHDR":
            size = struct.unpack(">II", body[:8])
        elif kind == b"eXIf" and size is not None and _turned(body):
            size = size[1], size[0]
    return size


def _webp(f: BinaryIO) -> tuple[int, int] | None:
    """After ``RIFF....WEBP``: a simple file's size from its image chunk (VP8 or VP8L); an extended file's
    from its VP8X chunk, turned as its EXIF chunk (after the image data) says."""
    kind, length = struct.unpack("<4sI", f.read(8))
    body = f.read(min(length, 32))
    if kind == b"VP8 ":
        width, height = struct.unpack("<HH", body[6:10])
        return width & 0x3FFF, height & 0x3FFF
    if kind == b"VP8L":
        bits = int.from_bytes(body[1:5], "little")
        return (bits & 0x3FFF) + 1, ((bits >> 14) & 0x3FFF) + 1
    if kind != b"VP8X":
        return None
    size = int.from_bytes(body[4:7], "little") + 1, int.from_bytes(body[7:10], "little") + 1
    if not body[0] & 0x08:   # no EXIF chunk
        return size
    f.seek(length - len(body) + (length & 1), os.SEEK_CUR)
    for _ in range(_MAX_SEGMENTS):
        kind, length = struct.unpack("<4sI", f.read(8))
        if kind == b"EXIF":
            body = f.read(min(length, 1 << 16))
            return (size[1], size[0]) if _turned(body[6:] if body[:6] == b"Exif\x00\x00" else body) else size
        f.seek(length + (length & 1), os.SEEK_CUR)
    return size


def _pnm(head: bytes) -> tuple[int, int] | None:
    """P1 to P6: width and height, the first two numbers after the magic, comments (# to line end) skipped."""
    numbers: list[int] = []
    for line in head[2:].split(b"\n"):
        for word in line.split(b"#", 1)[0].split():
            numbers.append(int(word))
            if len(numbers) == 2:
                return numbers[0], numbers[1]
    return None
