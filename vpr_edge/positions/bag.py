"""Positions from a bag's ``sensor_msgs/NavSatFix`` (lat, lon, alt) or ``nav_msgs/Odometry`` (x, y, z and the
yaw of its orientation) topic, interpolated in time to each image's stamp (rosbags, the ``ros`` extra)."""
from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from vpr_edge.errors import VprError
from vpr_edge.frames.bags import header_stamp, open_reader, topic_connections
from vpr_edge.positions.fill import at_times
from vpr_edge.positions.model import Positions

POSITION_TYPES = ("sensor_msgs/msg/NavSatFix", "nav_msgs/msg/Odometry")


def _yaw_deg(q) -> float:
    """A quaternion's yaw as a heading: degrees clockwise from +y (0 = along +y, 90 = along +x)."""
    yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))   # from +x, anticlockwise
    return (90.0 - math.degrees(yaw)) % 360.0


def bag_positions(path: str | os.PathLike[str], topic: str, stamps: np.ndarray) -> Positions:
    """Positions at the times ``stamps`` (seconds) from a NavSatFix or Odometry ``topic``: each coordinate
    interpolated linearly in time between the fixes either side (VprError for a stamp before the first fix
    or after the last, or a topic with no usable fix)."""
    path = Path(path)
    reader = open_reader(path)
    try:
        (conn, *_) = topic_connections(reader, path, topic, POSITION_TYPES, "positions_topic")
        geo = conn.msgtype.endswith("NavSatFix")
        rows = []
        for c, t_ns, raw in reader.messages(connections=[conn]):
            msg = reader.deserialize(raw, c.msgtype)
            if geo:
                if int(getattr(msg.status, "status", 0)) < 0:   # STATUS_NO_FIX
                    continue
                rows.append((header_stamp(msg, t_ns), msg.latitude, msg.longitude, msg.altitude, math.nan))
            else:
                p = msg.pose.pose.position
                rows.append((header_stamp(msg, t_ns), p.x, p.y, p.z, _yaw_deg(msg.pose.pose.orientation)))
    finally:
        reader.close()
    fix = np.array(sorted(rows), np.float64) if rows else np.zeros((0, 5))
    fix = fix[np.isfinite(fix[:, :3]).all(axis=1)]
    if len(fix) == 0:
        raise VprError(f"{path}: topic {topic} holds no usable position")
    return at_times(fix, stamps, "wgs84" if geo else "local", str(path), f"topic {topic}")
