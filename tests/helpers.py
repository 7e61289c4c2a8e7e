"""What several test modules share, defined once with one signature each: the command line run as a user
runs it, small recordings written for it (a video, a ROS bag), planted similarity rows along a driven route,
and the plain-loop references of the road (``stream``) matcher.

A test module imports these from here (``from helpers import planted``), never from another test module, so
that every module runs (or skips) on its own. Fixtures stay in ``conftest.py``.
"""
from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np

# --- the command line ---------------------------------------------------------------------------------------


def run(*args: object, timeout: float = 600, **kw) -> subprocess.CompletedProcess:
    """``vpr-edge ARGS`` in a new process (``python -m vpr_edge``), as a user runs it: text stdout / stderr
    captured; ``kw`` goes to ``subprocess.run`` (``cwd``, ``env`` ...)."""
    return subprocess.run([sys.executable, "-m", "vpr_edge", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, **kw)


def invoke(*args: object) -> tuple[int, str, str]:
    """``vpr-edge ARGS`` in this process (typer's CliRunner: fast, no start-up) -> (exit code, stdout, stderr)."""
    from typer.testing import CliRunner

    from vpr_edge.cli import app

    res = CliRunner().invoke(app, [str(a) for a in args])
    return res.exit_code, res.stdout, res.stderr


def assert_one_line_error(proc: subprocess.CompletedProcess, *needles: str) -> None:
    """A failed command said why in exactly one ``vpr-edge: error:`` line holding every needle, no traceback."""
    assert proc.returncode != 0
    assert "Traceback" not in proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("vpr-edge: error:")]
    assert len(lines) == 1, proc.stderr
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


# --- recordings -----------------------------------------------------------------------------------------------


def write_video(path: Path, frames: Path, count: int) -> Path:
    """The first ``count`` images of the folder ``frames`` (160x120) as an MJPG video at 10 fps at ``path``."""
    import cv2

    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (160, 120))
    for f in sorted(frames.iterdir())[:count]:
        w.write(cv2.imread(str(f)))
    w.release()
    return path


BAG_T0 = 1_700_000_000   # seconds: the stamp of a written bag's first image


def _bag_header(ts, i: int, dt: float = 0.1):
    t = BAG_T0 + i * dt
    Time, Header = ts.types["builtin_interfaces/msg/Time"], ts.types["std_msgs/msg/Header"]
    extra = {"seq": i} if "seq" in Header.__dataclass_fields__ else {}
    return Header(stamp=Time(sec=int(t), nanosec=int(round((t - int(t)) * 1e9))), frame_id="camera", **extra)


def _bag_image(ts, i: int, path: Path, raw: bool):
    import cv2

    bgr = cv2.imread(str(path))
    if raw:
        Image = ts.types["sensor_msgs/msg/Image"]
        h, w = bgr.shape[:2]
        return Image(header=_bag_header(ts, i), height=h, width=w, encoding="bgr8", is_bigendian=0, step=w * 3,
                     data=np.ascontiguousarray(bgr).reshape(-1))
    Compressed = ts.types["sensor_msgs/msg/CompressedImage"]
    return Compressed(header=_bag_header(ts, i), format="jpeg",
                      data=np.frombuffer(cv2.imencode(".jpg", bgr)[1], np.uint8))


def _bag_fix(ts, i: int, odometry: bool):
    if odometry:   # along +x: yaw 0 (heading 90, clockwise from +y)
        m = ts.types
        pose = m["geometry_msgs/msg/Pose"](position=m["geometry_msgs/msg/Point"](x=2.0 * i, y=1.0, z=0.0),
                                           orientation=m["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))
        return m["nav_msgs/msg/Odometry"](
            header=_bag_header(ts, i, 0.2), child_frame_id="base",
            pose=m["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
            twist=m["geometry_msgs/msg/TwistWithCovariance"](
                twist=m["geometry_msgs/msg/Twist"](linear=m["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                                                   angular=m["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)),
                covariance=np.zeros(36)))
    Status, Fix = ts.types["sensor_msgs/msg/NavSatStatus"], ts.types["sensor_msgs/msg/NavSatFix"]
    return Fix(header=_bag_header(ts, i, 0.2), status=Status(status=0, service=1), latitude=60.0 + i * 2e-5,
               longitude=10.0, altitude=5.0, position_covariance=np.zeros(9), position_covariance_type=0)


def write_bag(path: Path, frames: list[Path], kind: str, raw: bool = False, odometry: bool = False) -> Path:
    """A bag with /camera/image (compressed, or raw ``bgr8``) at 10 Hz from ``BAG_T0`` and /gps/fix
    (NavSatFix, or Odometry on /odom) at 5 Hz covering the images. ``kind``: ros1, ros2 (sqlite3) or mcap
    (ROS 2 MCAP storage). Needs rosbags (the ``ros`` extra): a caller without it skips."""
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin, Writer as Writer2
    from rosbags.typesys import Stores, get_typestore

    image_type = "sensor_msgs/msg/Image" if raw else "sensor_msgs/msg/CompressedImage"
    fix_topic, fix_type = ("/odom", "nav_msgs/msg/Odometry") if odometry else ("/gps/fix", "sensor_msgs/msg/NavSatFix")
    n_fix = math.ceil(len(frames) / 2) + 1
    if kind == "ros1":
        ts = get_typestore(Stores.ROS1_NOETIC)
        writer, serialize = Writer1(path), ts.serialize_ros1
    else:
        plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
        ts = get_typestore(Stores.ROS2_HUMBLE)
        writer, serialize = Writer2(path, version=9, storage_plugin=plugin), ts.serialize_cdr
    with writer as w:
        cam = w.add_connection("/camera/image", image_type, typestore=ts)
        fix = w.add_connection(fix_topic, fix_type, typestore=ts)
        for i, f in enumerate(frames):
            w.write(cam, int((BAG_T0 + i * 0.1) * 1e9), serialize(_bag_image(ts, i, f, raw), image_type))
        for i in range(n_fix):
            w.write(fix, int((BAG_T0 + i * 0.2) * 1e9), serialize(_bag_fix(ts, i, odometry), fix_type))
    return path


# --- planted routes -------------------------------------------------------------------------------------------


def places_at_speeds(speed_runs: list[tuple[float, int]], start: float = 0.0) -> np.ndarray:
    """The place (reference index) of each frame of a vehicle that starts at ``start`` and drives each
    (speed in places a frame, frames) run in turn -> (F,) int. Speed 0 is a stop."""
    pos, out = start, []
    for speed, frames in speed_runs:
        for _ in range(frames):
            out.append(int(pos))
            pos += speed
    return np.array(out)


def planted(rng: np.random.Generator, n_refs: int, places: np.ndarray, noise: float = 0.35,
            signal: float = 1.0) -> np.ndarray:
    """Similarity rows (F, R) for a vehicle at ``places`` (-1 = off the map): ``signal`` added at the true
    place over independent normal noise of spread ``noise``, as cosine similarities of encodings behave."""
    sim = noise * rng.normal(size=(len(places), n_refs))
    on = places >= 0
    sim[np.flatnonzero(on), places[on]] += signal
    return sim


def stop_cues(places: np.ndarray, moving: float = 0.0) -> np.ndarray:
    """A motion cue per frame of a planted route: 1.0 where the frame repeats the place before (the camera
    stands), ``moving`` elsewhere (0: a typical moving step)."""
    return np.where(np.r_[False, places[1:] == places[:-1]], 1.0, moving)


def unit_rows(x: np.ndarray) -> np.ndarray:
    """Each row of ``x`` scaled to length 1."""
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def exposures(rng: np.random.Generator, views: np.ndarray, cosine: float) -> np.ndarray:
    """New exposures of the unit ``views`` (n, D): each at ``cosine`` to its view, in a random direction."""
    noise = rng.normal(size=views.shape)
    noise -= (noise * views).sum(1, keepdims=True) * views
    return cosine * views + np.sqrt(1 - cosine ** 2) * unit_rows(noise)


def planted_drives(order: list[int], counts: list[int], noise: float, seed: int, speed: float = 1.0):
    """A route driven through a map of several drives in ``order`` (indices into ``counts``, the drives'
    lengths), the map holding them in index order -> (similarities (F, R) peaked at the true place and half as
    much at its neighbours in its drive, each frame's true place (F,), the map's ``Drives``)."""
    from vpr_edge.map.drives import Drives

    drives = Drives.of([f"d{i}" for i in range(len(counts))], counts)
    driven = np.concatenate([np.arange(drives.items[k].first, drives.items[k].last + 1) for k in order])
    truth = driven[np.arange(0, len(driven), speed).astype(int)]
    rng = np.random.default_rng(seed)
    sim = rng.normal(0.0, noise, (len(truth), drives.n_refs))
    for i, t in enumerate(truth):
        first, last = drives.items[drives.index(t)].first, drives.items[drives.index(t)].last
        sim[i, t] += 1.0
        sim[i, max(first, t - 1)] += 0.5
        sim[i, min(last, t + 1)] += 0.5
    return sim, truth, drives


# --- the road (stream) matcher as plain loops -------------------------------------------------------------------


def naive_road(sim, vmax, grid, decay, bias, turn, memory, lock, rival_window, stop_gain, stop_decay, still=0.0,
               cues=None, route=None, evidence=None, evidence_decay=None, unique=None, confirm=None, stuck=None,
               trust=None, why=None):
    """RoadMatcher written as plain loops over states, from its docstring, on one drive, every reference read
    every frame -> [(ref, score)] a frame. ``cues``: each frame's motion cue (NaN = none); ``route``: the
    references where the map's drive stood; ``evidence``, ``evidence_decay``, ``unique``, ``confirm``,
    ``stuck``, ``trust``: None = the default;
    ``why``: a list that gets each frame's reason, as ``RoadMatcher.why``."""
    from vpr_edge.matchers import MATCHERS

    defaults = MATCHERS["stream-rules"].params
    unique = defaults["unique"] if unique is None else unique
    confirm = defaults["confirm"] if confirm is None else confirm
    stuck = defaults["stuck"] if stuck is None else stuck
    trust = defaults["trust"] if trust is None else trust
    evidence = defaults["evidence"] if evidence is None else evidence
    evidence_decay = defaults["evidence_decay"] if evidence_decay is None else evidence_decay
    recent = None   # the answer's standing out of its rows, averaged over moving frames
    n_refs = sim.shape[1]
    n_speeds, n_pos = int(round(vmax * grid)) + 1, n_refs * grid
    h = np.zeros((n_speeds, n_pos))
    mean, weight, stopped, out, position = np.zeros(n_refs), memory, False, [], None
    held, last = 0, None   # frames the answer's place has held (each within rival_window of the one before)
    anchor, kept = None, 0   # where the answer last moved on to (one ahead, or more than one back); moving frames since
    for t, s in enumerate(sim):
        cue = np.nan if cues is None else cues[t]
        gain, s_decay, stands = stop_gain, stop_decay, False   # no cue: the stop_gain rule
        if still > 0 and cue == cue:
            gain, s_decay, stands = 0.0, decay, cue >= still
            if stands and route is not None and position is not None:   # the map's drive stood here too
                nxt = int(round(position)) + 1
                stands = not (nxt < n_refs and route[nxt])
        if not stands:   # a standing camera's frame leaves the state (and the hub means) as they were
            z = (s - s.mean()) / s.std()
            zr = z - mean
            if not stopped:
                weight = (1 - 1 / memory) * weight + 1
                mean = mean + (z - mean) / weight
            new = np.zeros_like(h)
            for v in range(n_speeds):
                for p in range(n_pos):
                    prev = max((h[u, p - v] - turn * abs(v - u) for u in range(n_speeds)),
                               default=0.0) if p >= v else 0.0
                    e = zr[p // grid] - bias
                    if v == 0:   # speed 0: decays by s_decay, a positive excess counts gain of itself
                        new[v, p] = max(0.0, max(0.0, s_decay * prev) + (gain * e if e > 0 else e))
                    else:
                        new[v, p] = max(0.0, max(0.0, decay * prev) + e)
            h = new
        v_best, p_best = np.unravel_index(np.argmax(h), h.shape)
        stopped, ref, best, position = v_best == 0, p_best // grid, h[v_best, p_best], p_best / grid
        rival = max([h[:, p].max() for p in range(n_pos) if abs(p // grid - ref) > rival_window], default=0.0)
        here = max((s[r] - s.mean()) / s.std() for r in range(max(0, ref - 1), min(n_refs, ref + 2)))
        if recent is None:
            recent = here
        else:   # a standing frame may raise the average, not lower it
            avg = evidence_decay * recent + (1 - evidence_decay) * here
            recent = max(recent, avg) if stands else avg
        uniqueness = 1 - (rival + 1) / (best + 1)
        held = held + 1 if last is not None and abs(ref - last) <= rival_window else 1
        last = ref
        if anchor is None or ref - anchor >= 1 or ref - anchor < -1:
            anchor, kept = ref, 0
        elif still > 0 and cue == cue and not stands:   # the cue says the camera moved
            kept += 1
        stuck_now = 0 < stuck <= kept
        view = recent >= evidence or uniqueness >= trust   # an unambiguous trajectory outweighs a weak view
        out.append((ref, float(best >= lock and held >= confirm and not stuck_now and view
                               and uniqueness >= unique) + uniqueness))
        if why is not None:   # the first condition of the lock that fails
            why.append("weak-view" if not view else "no-trajectory" if best < lock or held < confirm
                       or stuck_now else
                       "ambiguous" if uniqueness < unique else "locked")
    return out


def naive_road_local(sim, vmax, grid, decay, bias, turn, memory, lock, rival_window, window, probe, check, span,
                     hold, stop_gain, stop_decay, evidence, evidence_decay, unique, confirm=1, trust=1.0, **_):
    """RoadMatcher's local search as plain loops, from its docstring (no motion cue): while firmly locked
    (H >= hold * lock, nothing beyond the window half as strong) the next frame reads only the references
    within ``window`` of the answer and the ``probe`` sample (which gives the frame's mean and spread), state
    outside the window held at 0; ``span`` frames in every ``check`` firmly locked ones, and every frame not
    firmly locked, read the whole route. Running means count time, not updates. ``confirm``: frames the
    answer's place must have held (each within rival_window of the one before); ``trust``: the uniqueness at
    which a weak view does not lose the frame. -> [(ref, score, local)]."""
    n_refs = sim.shape[1]
    n_speeds, n_pos = int(round(vmax * grid)) + 1, n_refs * grid
    w = window if window and n_refs > 4 * window else 0
    probe_refs = np.sort(np.random.default_rng(0).choice(n_refs, min(n_refs, probe), replace=False))
    h = np.zeros((n_speeds, n_pos))
    mean, weight, seen = np.zeros(n_refs), np.full(n_refs, float(memory)), np.zeros(n_refs, int)
    t, stopped, win, held_for, recent, out = 0, False, None, 0, None, []
    place_held, last = 0, None
    for s in sim:
        lo, hi = win if win is not None else (0, n_refs)
        sample = s[probe_refs] if win is not None else s
        mu, sd = sample.mean(), max(sample.std(), 1e-12)
        zr = {}
        if not stopped:
            t += 1
        for r in range(lo, hi):
            z = (s[r] - mu) / sd
            zr[r] = z - mean[r]
            if not stopped:
                weight[r] = weight[r] * (1 - 1 / memory) ** (t - seen[r]) + 1
                seen[r] = t
                mean[r] += (z - mean[r]) / weight[r]
        new = h.copy()
        for v in range(n_speeds):
            for p in range(lo * grid, hi * grid):
                prev = max(h[u, p - v] - turn * abs(v - u) for u in range(n_speeds)) if p >= v else 0.0
                e = zr[p // grid] - bias
                if v == 0:
                    new[v, p] = max(0.0, max(0.0, stop_decay * prev) + (stop_gain * e if e > 0 else e))
                else:
                    new[v, p] = max(0.0, max(0.0, decay * prev) + e)
        h = new
        part = h[:, lo * grid:hi * grid]
        v_best, p_best = np.unravel_index(np.argmax(part), part.shape)
        stopped, ref, best = v_best == 0, lo + p_best // grid, part[v_best, p_best]
        per_ref = {r: h[:, r * grid:(r + 1) * grid].max() for r in range(lo, hi)}
        rival = max([x for r, x in per_ref.items() if abs(r - ref) > rival_window], default=0.0)
        here = max((s[r] - mu) / sd for r in range(max(lo, ref - 1), min(hi, ref + 2)))
        recent = here if recent is None else evidence_decay * recent + (1 - evidence_decay) * here
        uniqueness = 1 - (rival + 1) / (best + 1)
        place_held = place_held + 1 if last is not None and abs(ref - last) <= rival_window else 1
        last = ref
        out.append((ref, float(best >= lock and place_held >= confirm and (recent >= evidence or uniqueness >= trust)
                               and uniqueness >= unique) + uniqueness, win is not None))
        far = max([x for r, x in per_ref.items() if abs(r - ref) > w], default=0.0)
        held = bool(w) and best >= hold * lock and far < 0.5 * best
        held_for = held_for + 1 if held else 0
        if not held_for or held_for % check >= check - span:
            win = None
            continue
        nlo, nhi = max(0, ref - w), min(n_refs, ref + w + 1)
        keep = np.zeros(n_pos, bool)
        keep[nlo * grid:nhi * grid] = True
        if win is not None:   # what the previous window held and the new one does not is dropped
            keep[:win[0] * grid] = keep[win[1] * grid:] = True
            keep[nlo * grid:nhi * grid] = True
        h[:, ~keep] = 0.0
        win = (nlo, nhi)
    return out


def naive_predecessors(graph, grid: int, n_speeds: int) -> dict[tuple[int, int], list[int]]:
    """The road matcher's state columns' predecessors on the map of several drives ``graph``, by loops: for
    each (speed v >= 1, column c), the column v back within c's drive, or none before the drive's start, and
    across each junction into c's drive the source columns a trajectory at speed v comes from."""
    cols = graph.n_refs * grid
    first_col = np.array([graph.bounds(c // grid)[0] * grid for c in range(cols)])
    preds: dict[tuple[int, int], list[int]] = {}
    for c in range(cols):
        for v in range(1, n_speeds):
            p = c - v
            preds[(v, c)] = [p] if p >= first_col[c] else []
    for sources, targets in graph.junctions:
        for t in targets:
            for v in range(1, n_speeds):
                for i in range(v):
                    c = t * grid + i
                    if c >= (graph.bounds(t)[1] + 1) * grid:
                        continue
                    for s in sources:
                        p = s * grid + grid - (v - i)
                        if p >= graph.bounds(s)[0] * grid:
                            preds[(v, c)].append(p)
    return preds


def naive_road_over_drives(sim: np.ndarray, graph, grid: int, vmax: float, decay: float, bias: float,
                           turn: float, stop_gain: float, stop_decay: float) -> np.ndarray:
    """The road matcher's state (speeds x positions) after the last row over a map of several drives (the
    ``RouteGraph`` ``graph``), by loops over a predecessor list: in-drive ``c - v`` plus each junction's
    virtual predecessors; the whole route read, no running means, no motion cue."""
    r = sim.shape[1]
    n_speeds = int(round(vmax * grid)) + 1
    cols = r * grid
    preds = naive_predecessors(graph, grid, n_speeds)
    h = np.zeros((n_speeds, cols))
    for row in sim:
        z = np.repeat((row - row.mean()) / row.std(), grid) - bias
        m = np.array([[max(h[u, c] - turn * abs(v - u) for u in range(n_speeds)) for c in range(cols)]
                      for v in range(n_speeds)])
        new = np.zeros_like(h)
        for c in range(cols):
            new[0, c] = max(0.0, stop_decay * m[0, c]) + (stop_gain * max(z[c], 0.0) + min(z[c], 0.0))
            for v in range(1, n_speeds):
                ps = preds[(v, c)]
                before = max([m[v, p] for p in ps], default=0.0)
                new[v, c] = max(0.0, decay * before) + z[c]
        h = np.maximum(new, 0.0)
    return h


def naive_road_all(sim, graph, cues, route, candidates, *, vmax, grid, decay, bias, turn, memory, lock, window,
                   probe, check, span, hold, seek, peaks, stop_gain, stop_decay, still, **_):
    """RoadMatcher's trajectories with everything at once, as plain loops over states, from its docstrings:
    a map of several drives (the ``RouteGraph`` ``graph``: each state's predecessors listed, in its drive and
    across the junctions), the motion cue (``cues`` (F,), NaN = none; ``route``: the references where the
    map's drive stood), the local search around a firm lock (the lock's rules' firm test), and an index
    (``candidates[i]``: frame i's candidates, None: none), whose frames that would read the whole route read
    the places within ``seek`` of each candidate and the neighbourhoods of the best hypotheses held instead.
    The state is one (speeds, places * grid) array, zero outside what is held. -> per frame (ref, best H,
    the state after it, as the next frame's local search holds it, the references the frame read (None:
    all))."""
    from vpr_edge.matchers.route import merge

    n_refs = sim.shape[1]
    n_speeds, n_pos = int(round(vmax * grid)) + 1, n_refs * grid
    w = window if window and n_refs > 4 * window else 0
    gap = -(-n_speeds // grid) + 1
    probe_refs = np.sort(np.random.default_rng(0).choice(n_refs, min(n_refs, probe), replace=False))
    preds = naive_predecessors(graph, grid, n_speeds)
    h = np.zeros((n_speeds, n_pos))
    mean, weight, seen = np.zeros(n_refs), np.full(n_refs, float(memory)), np.full(n_refs, -1)
    t, stopped, position, win, held_for = 0, False, None, None, 0
    last_values: dict[int, float] = {}
    out = []
    for i, s in enumerate(sim):
        if win is None and candidates[i] is not None:   # an index: around its candidates and the hypotheses held
            reach = max(seek, w // 4)
            ranked = sorted(last_values.items(), key=lambda pv: -pv[1])[:4 * peaks]
            chosen: list[int] = []
            for p, v in ranked:
                if v <= 0 or len(chosen) == peaks:
                    break
                if all(abs(p - c) > 2 * reach for c in chosen):
                    chosen.append(p)
            near = [iv for c in set(int(c) for c in candidates[i]) for iv in graph.near(c, seek)]
            win = merge(near + [iv for p in chosen for iv in graph.near(p, reach)], gap)
            keep = np.zeros(n_pos, bool)
            for lo, hi in win:
                keep[lo * grid:hi * grid] = True
            h = np.where(keep, h, 0.0)
        searched = list(range(n_refs)) if win is None else [r for lo, hi in win for r in range(lo, hi)]
        read = None if win is None else searched + [int(r) for r in probe_refs]
        sample = s if win is None else s[probe_refs]
        mu, sd = sample.mean(), max(sample.std(), 1e-12)
        cue = cues[i]
        gain, s_decay, stands = stop_gain, stop_decay, False
        if still > 0 and cue == cue:
            gain, s_decay, stands = 0.0, decay, cue >= still
            if stands and route is not None and position is not None:
                nxt = int(round(position)) + 1
                stands = not (nxt < n_refs and route[nxt])
        if not stands:
            if not stopped:
                t += 1
            zr = {}
            for r in searched:
                z = (s[r] - mu) / sd
                zr[r] = z - mean[r]
                if not stopped:
                    weight[r] = weight[r] * (1 - 1 / memory) ** (1 if seen[r] < 0 else t - seen[r]) + 1
                    seen[r] = t
                    mean[r] += (z - mean[r]) / weight[r]
            m = np.array([[max(h[u, c] - turn * abs(v - u) for u in range(n_speeds)) for c in range(n_pos)]
                          for v in range(n_speeds)])
            new = np.zeros_like(h)
            for r in searched:
                for c in range(r * grid, (r + 1) * grid):
                    e = zr[r] - bias
                    new[0, c] = max(0.0, max(0.0, s_decay * m[0, c]) + (gain * e if e > 0 else e))
                    for v in range(1, n_speeds):
                        before = max([m[v, p] for p in preds[(v, c)]], default=0.0)
                        new[v, c] = max(0.0, max(0.0, decay * before) + e)
            h = new
        best, ref, col = -1.0, -1, 0
        values = {}
        for lo, hi in ([(0, n_refs)] if win is None else win):
            part = h[:, lo * grid:hi * grid]
            v_best, p_best = np.unravel_index(np.argmax(part), part.shape)
            if part[v_best, p_best] > best:
                best, ref, col = part[v_best, p_best], lo + p_best // grid, lo * grid + p_best
                stopped = v_best == 0
            values.update({r: h[:, r * grid:(r + 1) * grid].max() for r in range(lo, hi)})
        position, last_values = col / grid, values
        out.append((ref, best, h, read))   # the state as the next frame's search leaves it (below)
        near_ref = {r for lo, hi in graph.near(ref, w) for r in range(lo, hi)}
        far = max([v for r, v in values.items() if r not in near_ref], default=0.0)
        held = bool(w) and best >= hold * lock and far < 0.5 * best
        held_for = held_for + 1 if held else 0
        if not held_for or held_for % check >= check - span:
            win = None
            continue
        win = graph.near(ref, w, gap)
        keep = np.zeros(n_pos, bool)
        for lo, hi in win:
            keep[lo * grid:hi * grid] = True
        h = np.where(keep, h, 0.0)
        out[-1] = (ref, best, h, read)
    return out


# --- encodings along a route (index and API tests) ----------------------------------------------------------


def alike_refs(n: int, dim: int, rho: float = 0.9, seed: int = 0) -> np.ndarray:
    """Unit references along a route: each place like the one before."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, dim)).astype(np.float32)
    for i in range(1, n):
        x[i] = rho * x[i - 1] + np.sqrt(1 - rho ** 2) * x[i]
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def driven_encodings(n_refs: int, frames: int, noise: float, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """References along a route, a vehicle driving part of it at changing speeds with a detour: (refs,
    query encodings, true places (-1 off the map))."""
    refs = alike_refs(n_refs, 64, seed=seed)
    rng = np.random.default_rng(seed + 1)
    pos, truth, queries = 100.0, [], []
    for t in range(frames):
        speed = [1.0, 2.0, 0.5, 1.5][(t // 60) % 4]
        if 200 <= t < 240:   # off the map
            truth.append(-1)
            queries.append(rng.normal(size=64))
            continue
        pos += speed
        truth.append(int(pos))
        queries.append(refs[int(pos)] + noise * rng.normal(size=64) / 8)
    q = np.asarray(queries, np.float32)
    return refs, q / np.linalg.norm(q, axis=1, keepdims=True), np.asarray(truth)


def mcap_answer_frames(path) -> list[int]:
    """The frame indices of the ``/vpr/answer`` messages mcap's own reader finds in a recording that may be
    cut short (a kill, a full disk: the file has no summary); reading stops where the file ends."""
    import json

    from mcap.reader import NonSeekingReader

    frames = []
    with open(path, "rb") as f:
        try:
            for _, channel, message in NonSeekingReader(f).iter_messages(log_time_order=False):
                if channel.topic == "/vpr/answer":
                    frames.append(json.loads(message.data)["frame_index"])
        except Exception:   # noqa: BLE001 - the file ends where the writer stopped
            pass
    return frames
