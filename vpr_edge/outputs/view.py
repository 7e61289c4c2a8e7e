"""``localize --view`` / ``--rerun FILE.rrd``: the stream in Rerun as it is matched (the ``view`` extra,
rerun-sdk). Each frame: the query frame beside the matched reference's picture, where the vehicle is on the
route, the score, the confidence and the lost flag over time, and a line when a lost stretch starts (with its
reason) or ends.

Entities (what a recording holds, read back with ``rerun.chunk.RrdReader``), per frame unless static:

- ``query/image``: the frame, JPEG, at most ``pictures.MAX_SIDE`` pixels (none for a stream of descriptors);
- ``reference/image``: the matched reference's image (``pictures.ReferencePictures``: from its drive's folder,
  or a card naming it), on a lost frame a card saying lost and why;
- ``route/vehicle``: one point where the answer puts the vehicle, drawn on ``route/map`` (static: the map's
  drives), in the map's frame: x, y metres, or east, north metres from the map's first place for lat/lon (no
  map tiles: a vehicle fetches nothing), or the reference index along x where the map has no positions; the
  2D view's y points down, so north (+y) is drawn up by logging -y. On a lost frame: the last answered place,
  grey, labelled lost (no point before the first answer);
- ``timeseries/where/...``: metres along the route (or the reference index), answered frames only;
  ``timeseries/score/score`` and ``.../lost_line``; ``timeseries/state/lost`` (0/1) and ``.../confidence``;
- ``answer``: the output line's fields (``api.FIELDS``) as the components of an ``Answer`` (columns
  ``Answer:frame``, ``Answer:lost``, ...; a field that is None is left out);
- ``status``: a text line when a lost stretch starts (why) or ends, and when the stream stops early.

Timelines: ``frame`` (the frame's index in the stream) and, for frames with a time, ``time`` (the frame's own
``Match.stamp``: a Unix time as a timestamp, a video's presentation time as a duration); Rerun adds
``log_time``, when the answer was logged.

The ``.rrd`` file is written as the stream goes (``part``): Rerun's file sink streams into ``NAME.part``,
flushed within a second of each frame, frames or none (``Flusher``, ``FLUSH_INTERVAL_S``), so that after a
kill ``RrdReader(...).stream()`` reads every frame but the last second's. ``NAME.part`` becomes ``NAME`` when
the stream ends or is stopped; after a failure it stays, beside an older ``NAME``; the next run to ``NAME``
makes a killed run's part ``NAME``."""
from __future__ import annotations

import contextlib
import os
import uuid
from pathlib import Path

import numpy as np

from vpr_edge.api import FIELDS, Match
from vpr_edge.errors import warn
from vpr_edge.frames.frame import Frame
from vpr_edge.map import PlaceMap
from vpr_edge.outputs.part import Flusher, finish, open_output
from vpr_edge.outputs.pictures import ReferencePictures, card, jpeg
from vpr_edge.positions import EARTH_RADIUS_M

APP_ID = "vpr-edge"
UNIX_AFTER_S = 1e9      # a stamp from this on (2001) is a Unix time, below it a time from the stream's start
ANSWERED, LOST, ROUTE = (40, 170, 60), (150, 150, 150), (120, 120, 200)


def route_xy(place_map: PlaceMap) -> np.ndarray:
    """(R, 2) where each reference is drawn: x, y metres; east, north metres from the first place (lat/lon,
    equirectangular at the first place's latitude); or (reference index, 0) without positions."""
    p = place_map.positions
    if p is None:
        return np.stack([np.arange(len(place_map.names), dtype=np.float64), np.zeros(len(place_map.names))], 1)
    if not p.geo:
        return np.asarray(p.coords, np.float64)
    lat0, lon0 = p.coords[0]
    rad = np.pi / 180.0
    return np.stack([EARTH_RADIUS_M * rad * (p.coords[:, 1] - lon0) * np.cos(lat0 * rad),
                     EARTH_RADIUS_M * rad * (p.coords[:, 0] - lat0)], 1)


def answer_xy(place_map: PlaceMap, route: np.ndarray, m: Match) -> np.ndarray | None:
    """(2,) where answer ``m`` is drawn (as ``route_xy``; its interpolated place where it has one), None when
    lost."""
    if m.lost or m.ref_index is None:
        return None
    if m.x is not None and m.y is not None:
        return np.array([m.x, m.y])
    if m.lat is not None and m.lon is not None:
        p = place_map.positions
        assert p is not None
        lat0, lon0 = p.coords[0]
        rad = np.pi / 180.0
        return np.array([EARTH_RADIUS_M * rad * (m.lon - lon0) * np.cos(lat0 * rad),
                         EARTH_RADIUS_M * rad * (m.lat - lat0)])
    return route[m.ref_index].copy()


def _down(xy: np.ndarray) -> np.ndarray:
    """Map coordinates -> the 2D view's (y down): north up."""
    return xy * np.array([1.0, -1.0])


class RerunSink:
    """A ``sink.ResultSink`` logging each answer to Rerun: to a Viewer (``view``: ``viewer.start_viewer``) and
    / or to an ``.rrd`` file (``record``: written as the module says).
    ``map_path``: where the map was opened from (a relative drive folder is looked for from there too);
    ``stream``: the stream's name for the title; ``lost_line``: the score below which a frame is lost, drawn
    beside the score (None: not drawn)."""

    def __init__(self, place_map: PlaceMap, map_path: str | os.PathLike[str], *, view: bool = False,
                 record: str | os.PathLike[str] | None = None, stream: str = "stream",
                 lost_line: float | None = None, port: int | None = None) -> None:
        import rerun as rr

        from vpr_edge.outputs import viewer

        self.rr = rr
        self.map = place_map
        self.lost_line = lost_line
        self.pictures = ReferencePictures(place_map, map_path)
        self.route = route_xy(place_map)
        sinks = [rr.GrpcSink(viewer.start_viewer(port or viewer.PORT))] if view else []
        self._stack = contextlib.ExitStack()
        self.target = self.part = self._was = None
        with contextlib.ExitStack() as undo:     # a failure here leaves no part
            undo.push(self._stack)
            if record is not None:
                self.target, self._was, self.part, fd = open_output(Path(record), recover)
                self._stack.callback(os.close, fd)      # the lock, released last
                undo.callback(self.part.unlink, missing_ok=True)
                sinks.append(rr.FileSink(str(self.part)))
            self.rec = rr.RecordingStream(APP_ID, recording_id=str(uuid.uuid4()))
            self.rec.set_sinks(*sinks, default_blueprint=self._blueprint(Path(map_path).name, stream))
            self._flusher = Flusher(self.rec.flush)     # the SDK's logging is thread-safe: no lock taken
            self._stack.callback(self._flusher.stop)
            undo.pop_all()
        self._last: np.ndarray | None = None
        self._state: str | None = "start"     # the last status said: None answering, else why lost
        self._cards: dict[str, bytes] = {}
        self._log_static(Path(map_path).name, stream)

    def _blueprint(self, map_name: str, stream: str):
        import rerun.blueprint as rrb

        where = "metres along the route" if self.map.positions is not None else "reference index"
        return rrb.Blueprint(rrb.Horizontal(
            rrb.Vertical(rrb.Spatial2DView(origin="/query", name=f"query frame ({stream})"),
                         rrb.Spatial2DView(origin="/reference", name=f"matched reference ({map_name})")),
            rrb.Vertical(rrb.Spatial2DView(origin="/route", name="where on the route"),
                         rrb.TimeSeriesView(origin="/timeseries/where", name=where),
                         rrb.TimeSeriesView(origin="/timeseries/score", name="score and the lost line"),
                         rrb.TimeSeriesView(origin="/timeseries/state", name="lost (0/1) and confidence"),
                         rrb.TextLogView(origin="/status", name="lost stretches")),
            column_shares=[1, 1]), collapse_panels=True)

    def _log_static(self, map_name: str, stream: str) -> None:
        rr, rec = self.rr, self.rec
        strips = [_down(self.route[d.first:d.last + 1]) for d in self.map.drives.items]
        strips = [s if len(s) > 1 else np.repeat(s, 2, 0) for s in strips]
        rec.log("route/map", rr.LineStrips2D(strips, colors=[ROUTE], radii=rr.Radius.ui_points(2.0),
                                             labels=[d.name for d in self.map.drives.items]), static=True)
        rec.log("route/map/places", rr.Points2D(_down(self.route), colors=[ROUTE],
                                                radii=rr.Radius.ui_points(1.5)), static=True)
        frame = "no positions: reference index" if self.map.positions is None else \
            "lat/lon as east/north metres" if self.map.positions.geo else "x/y metres"
        rec.log("description", rr.TextDocument(f"map {map_name} ({len(self.map.names)} places, {frame}), "
                                               f"stream {stream}"), static=True)
        for name in ("score", "lost_line"):
            rec.log(f"timeseries/score/{name}", rr.SeriesLines(names=name.replace("_", " ")), static=True)
        rec.log("timeseries/state/lost", rr.SeriesLines(names="lost"), static=True)
        rec.log("timeseries/state/confidence", rr.SeriesLines(names="confidence"), static=True)

    def _lost_card(self, why: str | None) -> bytes:
        key = why or ""
        if key not in self._cards:
            self._cards[key] = jpeg(card(["lost", f"({why})" if why else ""], shade=60))
        return self._cards[key]

    def write(self, match: Match, frame: Frame | None) -> None:
        rr, rec, m = self.rr, self.rec, match
        rec.set_time("frame", sequence=m.frame_index)
        if m.stamp is not None:
            if m.stamp >= UNIX_AFTER_S:
                rec.set_time("time", timestamp=m.stamp)
            else:
                rec.set_time("time", duration=m.stamp)
        if frame is not None and frame.image is not None:
            rec.log("query/image", rr.EncodedImage(contents=jpeg(frame.image), media_type="image/jpeg"))
        if m.lost or m.ref_index is None:
            picture = self._lost_card(m.lost_why)
        else:
            picture, _ = self.pictures.picture(m.ref_index)
        rec.log("reference/image", rr.EncodedImage(contents=picture, media_type="image/jpeg"))
        xy = answer_xy(self.map, self.route, m)
        if xy is not None:
            self._last = xy
            rec.log("route/vehicle", rr.Points2D(_down(xy[None]), colors=[ANSWERED], radii=rr.Radius.ui_points(7.0),
                                                 labels=[m.ref or str(m.ref_index)]))
            along = m.along_m if m.along_m is not None else float(m.ref_index)  # type: ignore[arg-type]
            rec.log("timeseries/where/along", rr.Scalars(along))
        elif self._last is not None:
            rec.log("route/vehicle", rr.Points2D(_down(self._last[None]), colors=[LOST],
                                                 radii=rr.Radius.ui_points(7.0),
                                                 labels=[f"lost ({m.lost_why})" if m.lost_why else "lost"]))
        else:
            rec.log("route/vehicle", rr.Points2D(np.zeros((0, 2))))
        rec.log("timeseries/score/score", rr.Scalars(float(m.score)))
        if self.lost_line is not None:
            rec.log("timeseries/score/lost_line", rr.Scalars(float(self.lost_line)))
        rec.log("timeseries/state/lost", rr.Scalars(float(m.lost)))
        if m.confidence is not None:
            rec.log("timeseries/state/confidence", rr.Scalars(float(m.confidence)))
        fields = m.fields()
        rec.log("answer", rr.DynamicArchetype("Answer", components={k: fields[k] for k in FIELDS}))
        state = (m.lost_why or "no reason given") if m.lost else None
        if state != self._state:
            if state is not None:
                rec.log("status", rr.TextLog(f"frame {m.frame_index}: lost ({state})", level="WARN"))
            elif self._state != "start":
                rec.log("status", rr.TextLog(f"frame {m.frame_index}: answering again", level="INFO"))
            self._state = state
        self._flusher.wrote()

    def close(self, complete: bool, failed: bool = False) -> None:
        """End the recording and make it ``NAME``; after a failure it stays ``NAME.part`` beside an older
        ``NAME``, and a warning says so."""
        self._flusher.stop()
        try:
            if not complete:
                self.rec.log("status", self.rr.TextLog("the stream stopped early", level="WARN"))
            self.rec.flush()
            self.rec.disconnect()
            if self.part is not None and failed:
                warn(f"{self.part}: the recording of a run that failed; {self.target} "
                     f"{'left as it was' if self._was is not None else 'not made'}")
            elif self.part is not None:
                finish(self.part, self.target, self._was)
        finally:
            self._stack.close()


def recover(part: Path, target: Path) -> str | None:
    """A killed run's recording (``part.Recover``): made ``target`` as it is (Rerun reads a recording cut
    short up to where it ends); None, ``target`` untouched, when the kill came before a whole record."""
    from rerun.chunk import RrdReader

    try:
        next(iter(RrdReader(part).stream()), None)
    except Exception:   # noqa: BLE001 - too short to hold a record: nothing to keep
        return None
    os.replace(part, target)
    return f"made {target} as it is"
