"""``localize -o run.mcap``: the answers as an MCAP file (the ``mcap`` extra) to open in Foxglove beside the
drive's own recording. JSON messages with JSON-schema schemas, Foxglove's well-known ones for places:

- ``/vpr/answer`` (schema "vpr_edge.Answer"): every frame's output line, the fields of ``api.FIELDS`` as the JSON
  lines output writes them (docs/formats.md);
- ``/vpr/location`` (``foxglove.LocationFix``): where the answer puts the vehicle, on maps with lat/lon (the
  Map panel); altitude from the map's place where known, else 0; the heading in radians clockwise from north;
- ``/vpr/pose`` (``foxglove.PoseInFrame``, frame ``map``): the same on maps with x/y metres (the 3D panel);
  orientation the heading about +z where known (heading is clockwise from +y), else none (identity).

A lost frame, and every frame of a map without positions, has an answer message only. Each message is logged
at the frame's own time (``Match.stamp``: a bag's header stamps, a video's presentation time from its start, a
timestamps file's times), so that it lines up with the drive's recording; a frame without a time is logged at
the time its answer was made (arrival), as is the publish time of every message.

The file is written as the stream goes (``part``): into ``NAME.part``, in chunks handed to the system within a
second of their answers, frames or none (``Flusher``, ``FLUSH_INTERVAL_S``), so that after a kill mcap's own
reader reads every answer but the last second's (``mcap.reader.NonSeekingReader``,
``iter_messages(log_time_order=False)``: the file has no summary).
``NAME.part`` becomes ``NAME`` when the stream ends or is stopped, with its summary; after a failure it stays,
beside an older ``NAME``. The next run to ``NAME`` finalises a killed run's part into ``NAME`` (``recover``)."""
from __future__ import annotations

import contextlib
import json
import math
import os
import time
from pathlib import Path
from typing import IO

from vpr_edge.api import FIELDS, RESULTS_SCHEMA, Match
from vpr_edge.errors import VprError, warn
from vpr_edge.files.atomic import atomic_output
from vpr_edge.frames.frame import Frame
from vpr_edge.map import PlaceMap
from vpr_edge.outputs.part import Flusher, finish, open_output, writing

ANSWER, LOCATION, POSE = "/vpr/answer", "/vpr/location", "/vpr/pose"
FRAME_ID = "map"

_NUM, _INT, _STR = {"type": "number"}, {"type": "integer"}, {"type": "string"}
_TIME = {"type": "object", "title": "time", "properties": {"sec": {"type": "integer", "minimum": 0},
                                                           "nsec": {"type": "integer", "minimum": 0,
                                                                    "maximum": 999999999}}}
_XYZ = {"type": "object", "title": "foxglove.Vector3", "properties": {k: _NUM for k in "xyz"},
        "required": list("xyz")}
_QUAT = {"type": "object", "title": "foxglove.Quaternion", "properties": {k: _NUM for k in "xyzw"},
         "required": list("xyzw")}
_COLOR = {"type": "object", "title": "foxglove.Color", "properties": {k: _NUM for k in "rgba"},
          "required": list("rgba")}

LOCATION_FIX = {
    "title": "foxglove.LocationFix", "type": "object",
    "properties": {"timestamp": _TIME, "frame_id": _STR, "latitude": _NUM, "longitude": _NUM, "altitude": _NUM,
                   "position_covariance": {"type": "array", "items": _NUM, "minItems": 9, "maxItems": 9},
                   "position_covariance_type": {"title": "foxglove.PositionCovarianceType",
                                                "oneOf": [{"title": t, "const": i} for i, t in enumerate(
                                                    ("UNKNOWN", "APPROXIMATED", "DIAGONAL_KNOWN", "KNOWN"))]},
                   "heading": _NUM, "color": _COLOR},
    "required": ["timestamp", "frame_id", "latitude", "longitude", "altitude", "position_covariance",
                 "position_covariance_type"]}
POSE_IN_FRAME = {
    "title": "foxglove.PoseInFrame", "type": "object",
    "properties": {"timestamp": _TIME, "frame_id": _STR,
                   "pose": {"type": "object", "title": "foxglove.Pose",
                            "properties": {"position": _XYZ, "orientation": _QUAT},
                            "required": ["position", "orientation"]}},
    "required": ["timestamp", "frame_id", "pose"]}

_OPT_NUM, _OPT_INT, _OPT_STR = {"type": ["number", "null"]}, {"type": ["integer", "null"]}, {"type": ["string", "null"]}
ANSWER_TYPES = {"frame_index": _INT, "frame": _STR, "stamp": _OPT_NUM, "ref_index": _OPT_INT, "ref": _OPT_STR,
                "drive": _OPT_STR, "x": _OPT_NUM, "y": _OPT_NUM, "lat": _OPT_NUM, "lon": _OPT_NUM,
                "heading": _OPT_NUM, "along_m": _OPT_NUM, "score": _NUM, "confidence": _OPT_NUM,
                "lost": {"type": "boolean"}, "lost_why": _OPT_STR}
ANSWER_SCHEMA = {"title": "vpr_edge.Answer", "description": f"vpr-edge localize's output line (results schema "
                 f"{RESULTS_SCHEMA})", "type": "object", "properties": {k: ANSWER_TYPES[k] for k in FIELDS},
                 "required": list(FIELDS)}


def stamp_ns(seconds: float) -> int:
    """Seconds -> integer nanoseconds."""
    return int(round(seconds * 1e9))


def foxglove_time(ns: int) -> dict:
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def answer_line(m: Match) -> dict:
    """The output line as the JSON lines output writes it (floats but the stamp to 6 decimals)."""
    return {k: round(v, 6) if isinstance(v, float) and k != "stamp" else v for k, v in m.fields().items()}


def location_fix(m: Match, ns: int, altitude: float) -> dict:
    """``foxglove.LocationFix`` of an answer on a lat/lon map (``m.lat``, ``m.lon`` set)."""
    msg = {"timestamp": foxglove_time(ns), "frame_id": FRAME_ID, "latitude": m.lat, "longitude": m.lon,
           "altitude": altitude, "position_covariance": [0.0] * 9, "position_covariance_type": 0,
           "color": {"r": 0.16, "g": 0.67, "b": 0.24, "a": 1.0}}
    if m.heading is not None:
        msg["heading"] = math.radians(m.heading)
    return msg


def pose_in_frame(m: Match, ns: int) -> dict:
    """``foxglove.PoseInFrame`` of an answer on an x/y map (``m.x``, ``m.y`` set): z 0; the heading
    (clockwise from +y) as a rotation about +z (yaw 90 - heading degrees, counter-clockwise from +x)."""
    q = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}
    if m.heading is not None:
        yaw = math.radians(90.0 - m.heading)
        q = {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2), "w": math.cos(yaw / 2)}
    return {"timestamp": foxglove_time(ns), "frame_id": FRAME_ID,
            "pose": {"position": {"x": m.x, "y": m.y, "z": 0.0}, "orientation": q}}


def _read_whole(part: Path, what: str):
    """``what`` (messages or metadata) of a killed run's MCAP file, up to where the kill cut it."""
    from mcap.reader import NonSeekingReader

    with open(part, "rb") as f:
        reader = NonSeekingReader(f)
        items = reader.iter_messages(log_time_order=False) if what == "messages" else reader.iter_metadata()
        try:
            yield from items
        except Exception:   # noqa: BLE001 - the file ends where the kill cut it: what came before is kept
            return


def recover(part: Path, target: Path) -> str | None:
    """A killed run's MCAP file (``part.Recover``): its messages up to the last whole chunk, with their
    schemas, channels and metadata, written to ``target`` as a whole file; None (``target`` untouched) if it
    holds no message."""
    from mcap.writer import Writer

    if next(_read_whole(part, "messages"), None) is None:
        return None
    count = 0
    with atomic_output(target) as tmp, open(tmp, "wb") as out:
        writer = Writer(out)
        writer.start(profile="", library="vpr-edge")
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, message in _read_whole(part, "messages"):
            if schema is not None and schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(channel.topic, channel.message_encoding,
                                                               schemas.get(channel.schema_id, 0),
                                                               dict(channel.metadata))
            writer.add_message(channels[channel.id], message.log_time, message.data, message.publish_time,
                               message.sequence)
            count += 1
        for meta in _read_whole(part, "metadata"):
            writer.add_metadata(meta.name, dict(meta.metadata))
        writer.finish()
    return f"its {count} messages finalised as {target}"


class McapSink:
    """A ``sink.ResultSink`` writing each answer to an MCAP file at ``path`` (see the module's topics);
    ``place_map`` says which place topic the map has; ``meta``: strings stored in the file's ``vpr-edge``
    metadata record (e.g. the map and the stream)."""

    def __init__(self, path: str | os.PathLike[str], place_map: PlaceMap, meta: dict[str, str] | None = None) -> None:
        from mcap.writer import Writer

        from vpr_edge import __version__

        self.map = place_map
        self.target, self._was, self.part, self._fd = open_output(Path(path), recover)
        self._stack = contextlib.ExitStack()
        self._stack.callback(os.close, self._fd)   # the lock, released last
        with contextlib.ExitStack() as undo:      # a failure here leaves no part
            undo.push(self._stack)
            undo.callback(self.part.unlink, missing_ok=True)
            self._file: IO[bytes] = self._stack.enter_context(open(self._fd, "ab", closefd=False))
            self.writer = Writer(self._file)
            self.writer.start(profile="", library=f"vpr-edge {__version__}")
            self._channels = {ANSWER: self._channel(ANSWER, ANSWER_SCHEMA)}
            positions = place_map.positions
            if positions is not None:
                topic, schema = (LOCATION, LOCATION_FIX) if positions.geo else (POSE, POSE_IN_FRAME)
                self._channels[topic] = self._channel(topic, schema)
            self.writer.add_metadata("vpr-edge", {"version": __version__, "results_schema": str(RESULTS_SCHEMA),
                                                  **(meta or {})})
            self.writer.flush()
            self._flusher = Flusher(self.writer.flush)
            self._stack.callback(self._flusher.stop)
            undo.pop_all()
        self._sequence = 0

    def _channel(self, topic: str, schema: dict) -> int:
        sid = self.writer.register_schema(schema["title"], "jsonschema", json.dumps(schema).encode())
        return self.writer.register_channel(topic, "json", sid)

    def _add(self, topic: str, msg: dict, log_ns: int, publish_ns: int) -> None:
        self.writer.add_message(self._channels[topic], log_ns, json.dumps(msg).encode(), publish_ns, self._sequence)

    def write(self, match: Match, frame: Frame | None) -> None:
        with writing(str(self.part)), self._flusher.lock:
            self._flusher.check()
            self._write(match)
            self._flusher.wrote()

    def _write(self, match: Match) -> None:
        m = match
        arrival = time.time_ns()
        ns = arrival
        if m.stamp is not None:
            if m.stamp >= 0 and math.isfinite(m.stamp):
                ns = stamp_ns(m.stamp)
            else:   # said once (warn)
                warn("a frame time before 1970 or not finite: the MCAP messages of such frames are logged at "
                     "their arrival")
        self._add(ANSWER, answer_line(m), ns, arrival)
        if not m.lost and m.lat is not None and LOCATION in self._channels:
            alt = float(self.map.positions.altitude[m.ref_index]) if self.map.positions is not None and \
                m.ref_index is not None else float("nan")
            self._add(LOCATION, location_fix(m, ns, alt if math.isfinite(alt) else 0.0), ns, arrival)
        elif not m.lost and m.x is not None and POSE in self._channels:
            self._add(POSE, pose_in_frame(m, ns), ns, arrival)
        self._sequence += 1

    def close(self, complete: bool, failed: bool = False) -> None:
        """End the file with its summary and make it ``NAME``; after a failure (best effort: the disk may be
        full) it stays ``NAME.part`` beside an older ``NAME``, and a warning says so."""
        self._flusher.stop()
        try:
            try:
                with writing(str(self.part)):
                    self._flusher.check()
                    self.writer.finish()
                    self._file.flush()
                    if not failed:
                        finish(self.part, self.target, self._was)
                        return
            except VprError:
                if not failed:
                    raise
            finally:
                if self.part.exists():
                    warn(f"{self.part}: the recording of a run that failed; {self.target} "
                         f"{'left as it was' if self._was is not None else 'not made'}")
        finally:
            self._stack.close()
