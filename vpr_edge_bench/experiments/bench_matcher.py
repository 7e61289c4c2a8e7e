"""Online matcher benchmark: per-frame time and memory over a long synthetic stream against a large map.

    python -m vpr_edge_bench bench-matcher --matcher stream --refs 100000 --frames 10000 --dim 2048 --storage int8

A synthetic vehicle drives the mapped route with planted speed changes: every 20-200 frames it picks a new
speed in {0 (stopped), 0.5, 1, 2, 3} references per frame, and now and then leaves the route for a 50-frame
detour; each query encoding is a noisy copy of its true reference. Each frame costs the similarities the
matcher asks for (``matchers.step``: every reference, or a local search's window and probe) from references
stored as a map stores them (``index.encodings.Encodings``, --storage) and one update of the registered online
matcher. At each checkpoint it prints the mean per-frame time since the last checkpoint, current RSS (all;
the process's own, anonymous; pages of mapped files, i.e. of the map with --mmap) and peak RSS, R@1 (within
+-1 reference) over the mapped frames so far and the share of frames searched locally.
Random unit encodings of --dim dims: the similarity column scales with D. ``--coarse``: the frames that
search the whole route go through ``coarse.CoarseSearch`` as ``Localizer`` does on large maps.
``--cue``: each frame is matched with its motion cue as ``Localizer`` matches it (``matchers.MotionCue``:
its likeness to the last query that moved, timed with the match), and a stopped vehicle's frame is the previous
frame plus ``--stop-noise`` sensor noise (a standing camera sees its view again) instead of a fresh noisy copy
of the reference; without it no cue is given and a stop's frames are independent draws, as before.
"""
from __future__ import annotations

import argparse
import gc
import resource
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vpr_edge.errors import VprError
from vpr_edge.files.npz import read_npz, write_npz
from vpr_edge.index.coarse import CoarseSearch
from vpr_edge.index.encodings import STORAGES, Encodings
from vpr_edge.index.ivf import SequenceQuery, fit_ivf
from vpr_edge.matchers import get_matcher, step
from vpr_edge_bench.runner import parser, run_checked


def rss_mb(field: str = "VmRSS") -> float:
    """This process's resident memory in MB from /proc/self/status: ``VmRSS`` (all), ``RssAnon`` (its own
    memory: state, signs, buffers) or ``RssFile`` (pages of mapped files: a memory-mapped map's rows)."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1]) / 1024
    return float("nan")


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def main(argv: Sequence[str] | None = None) -> int:
    p = parser(__name__, __doc__)
    p.add_argument("--refs", type=int, default=10_000)
    p.add_argument("--frames", type=int, default=100_000)
    p.add_argument("--dim", type=int, default=256, help="encoding dimension of the synthetic map")
    p.add_argument("--noise", type=float, default=1.0, help="query noise relative to a unit reference")
    p.add_argument("--storage", default="float32", choices=STORAGES, help="how the map keeps the references")
    p.add_argument("--matcher", default="stream", help="registered online matcher")
    p.add_argument("--window", type=int, default=None, help="stream: local search half-width (0 = global)")
    p.add_argument("--param", action="append", default=[], metavar="KEY=VALUE",
                   help="set one of the matcher's parameters (repeatable), as localize --param reads it")
    p.add_argument("--coarse", action="store_true", help="whole-route frames by coarse.CoarseSearch (signs, "
                   "then exact values for the best candidates), as Localizer does on maps of 20,000+ references")
    p.add_argument("--mmap", type=Path, default=None, metavar="FILE",
                   help="write the stored references to FILE (a map-style .npz) and read them back memory-mapped, "
                   "as localize opens a map, so that RSS counts only the pages the frames touch")
    p.add_argument("--cue", action="store_true", help="give each frame its motion cue (cosine to the last query "
                   "that moved) and make a stopped vehicle's frames near-repeats of the one before")
    p.add_argument("--stop-noise", type=float, default=0.01,
                   help="with --cue: noise of a stopped frame relative to the previous one (default 0.01)")
    p.add_argument("--index", action="store_true", help="fit an index of the references (index.ivf, as build-map "
                   "does on large maps) and give whole-route frames its candidates, as Localizer does")
    p.add_argument("--walk", type=float, default=0.0, metavar="RHO", help="references along a route: each the "
                   "one before times RHO (< 1) plus fresh noise (consecutive places alike, as a real route's are; "
                   "0: independent random references)")
    p.add_argument("--checkpoints", default="1000,10000,100000")
    p.add_argument("--seed", type=int, default=0)
    a = p.parse_args(argv)
    return run_checked(__name__, lambda: _run(a))


def _run(a: argparse.Namespace) -> int:
    """The work of ``main``, its options checked before the synthetic map is built."""
    if not a.stop_noise >= 0:
        raise VprError(f"--stop-noise must be >= 0, got {a.stop_noise}")
    try:
        matcher = get_matcher(a.matcher)
        if a.window is not None:
            matcher = matcher.with_params(window=a.window)
        matcher = matcher.with_params(**matcher.parse_params(a.param))
    except ValueError as e:
        raise VprError(str(e)) from None
    rng = np.random.default_rng(a.seed)
    route = np.random.default_rng([a.seed, 1])   # the route's speeds and detours: the same whatever --dim
    refs = rng.normal(size=(a.refs, a.dim)).astype(np.float32)
    if a.walk:
        for i in range(1, a.refs):   # a route: each place like the one before (unit variance kept)
            refs[i] = a.walk * refs[i - 1] + np.sqrt(1.0 - a.walk ** 2) * refs[i]
    refs /= np.linalg.norm(refs, axis=1, keepdims=True)
    checkpoints = sorted(int(c) for c in a.checkpoints.split(",") if int(c) <= a.frames)
    dtw = matcher.stream(a.refs)
    stored = Encodings.pack(refs, a.storage)
    del refs
    if a.mmap is not None:
        write_npz(a.mmap, stored.to_arrays(), {"kind": "bench references", "schema": 1})
        del stored
        gc.collect()
        stored = Encodings.from_arrays(read_npz(a.mmap, "bench references", 1, mmap=True)[0], a.storage)
        print(f"references memory-mapped from {a.mmap}, RSS {rss_mb():.1f} MB")
    coarse = CoarseSearch(stored) if a.coarse else None
    index = None
    if a.index:
        t0 = time.perf_counter()
        index = fit_ivf(stored, seed=a.seed)
        print(f"index fitted in {time.perf_counter() - t0:.1f} s ({len(index.centroids)} lists)")
    if coarse is not None:
        t0 = time.perf_counter()
        coarse.signs
        print(f"signs packed in {1e3 * (time.perf_counter() - t0):.0f} ms ({coarse.signs.nbytes / 1e6:.1f} MB)")
    print(f"map {a.refs} refs x {a.dim} dims {a.storage} ({stored.values.nbytes / 1e6:.1f} MB), {a.frames} frames, "
          f"matcher {a.matcher} {matcher.params}, motion cue {'on' if a.cue else 'off'}")
    print(f"{'frames':>8s} {'ms/frame':>9s} {'sim ms':>7s} {'match ms':>8s} {'RSS MB':>8s} {'anon MB':>8s} "
          f"{'file MB':>8s} {'peak MB':>8s} {'acc+-1':>7s} {'local':>6s}")
    pos, detour, speed, until = 0.0, 0, 1.0, 0
    t_sim = t_dtw = 0.0
    correct = counted = local = 0
    last = 0
    sim_s = [0.0]
    previous: np.ndarray | None = None   # the last query (a standing camera's next frame repeats it)
    cue = matcher.motion_cue() if a.cue else None
    seq = SequenceQuery(matcher.params.get("seek_frames", 1))   # what the index is asked, as Localizer asks it

    def similarity(idx: np.ndarray | None) -> np.ndarray:
        t0 = time.perf_counter()
        row = coarse.similarity(q) if coarse is not None and idx is None else stored.similarity(q[None], idx)[0]
        sim_s[0] += time.perf_counter() - t0
        return row

    noise_scale = a.noise / np.sqrt(a.dim)
    for t in range(1, a.frames + 1):
        if detour == 0 and route.random() < 1e-3:
            detour = 50
        if detour:
            detour -= 1
            q = rng.normal(size=a.dim).astype(np.float32)
            true = -1
        else:
            if t >= until:
                speed, until = float(route.choice([0.0, 0.5, 1.0, 2.0, 3.0])), t + int(route.integers(20, 201))
            pos = (pos + speed) % a.refs
            true = int(pos)
            if a.cue and speed == 0.0 and previous is not None:   # a standing camera: its view again
                q = previous + a.stop_noise * noise_scale * rng.normal(size=a.dim).astype(np.float32)
            else:
                q = stored.dense_row(true) + noise_scale * rng.normal(size=a.dim).astype(np.float32)
        local += getattr(dtw, "wanted", lambda: None)() is not None
        sim_s[0] = 0.0
        t0 = time.perf_counter()
        seq.push(q)
        ref, _ = step(dtw, similarity, cue(q) if cue is not None else None,
                      None if index is None else (lambda: index.candidates(stored, seq.query())))
        t1 = time.perf_counter()
        previous = q
        t_sim += sim_s[0]
        t_dtw += t1 - t0 - sim_s[0]
        if true >= 0:
            counted += 1
            correct += abs(ref - true) <= 1 or abs(ref - true) >= a.refs - 1
        if t in checkpoints:
            n = t - last
            print(f"{t:8d} {1e3 * (t_sim + t_dtw) / n:9.3f} {1e3 * t_sim / n:7.3f} {1e3 * t_dtw / n:8.3f} "
                  f"{rss_mb():8.1f} {rss_mb('RssAnon'):8.1f} {rss_mb('RssFile'):8.1f} {peak_rss_mb():8.1f} "
                  f"{correct / max(counted, 1):7.3f} {local / n:6.2f}",
                  flush=True)
            last, t_sim, t_dtw, local = t, 0.0, 0.0, 0
    return 0

