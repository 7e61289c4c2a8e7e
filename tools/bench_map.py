#!/usr/bin/env python3
"""Map size, open time, RSS and similarity time at 1,000 / 10,000 / 100,000 places, real encoding size.

    python tools/bench_map.py --map samples.map.npz --refs 1000,10000,100000 [--storage int8] [--out /tmp/b]

Each synthetic map copies the encoder and metadata of the given real map (so its encodings have the real
IFV size, 2 x components x channels) and fills R references with random unit rows, written through
``map.save_map`` (the values are staged in a memory-mapped temporary file, never whole in RAM). Then, each
in a fresh process so that RSS means something: open with ``load_map(mmap=True)`` (what ``localize``
does) and with ``mmap=False`` (everything read into RAM), and time one similarity row (one query against
every reference), cold (first touch, pages read from the file cache or disk) and warm (mean of 3 more).
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


from vpr_edge.index.encodings import DTYPES, Encodings
from vpr_edge.map import PlaceMap, load_map, save_map

PROBE = r"""
import json, resource, sys, time
import numpy as np
from vpr_edge.map import load_map
def rss():
    for line in open("/proc/self/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
base = rss()
t0 = time.perf_counter()
pm = load_map(sys.argv[1], mmap=sys.argv[2] == "mmap")
t_open = time.perf_counter() - t0
rss_open = rss() - base
q = np.random.default_rng(0).normal(size=(1, pm.stored.shape[1])).astype(np.float32)
t0 = time.perf_counter(); pm.similarity(q); cold = time.perf_counter() - t0
t0 = time.perf_counter()
for _ in range(3):
    pm.similarity(q)
warm = (time.perf_counter() - t0) / 3
print(json.dumps({"open_s": t_open, "rss_open_mb": rss_open, "rss_after_mb": rss() - base,
                  "cold_ms": 1e3 * cold, "warm_ms": 1e3 * warm}))
"""


def synthetic_map(real: PlaceMap, refs: int, storage: str, out: Path, scratch: Path) -> None:
    """A map of ``refs`` random unit rows with ``real``'s codebook and metadata, written to ``out``."""
    d = real.stored.shape[1]
    rng = np.random.default_rng(refs)
    values = np.lib.format.open_memmap(scratch / "values.npy", mode="w+", dtype=DTYPES[storage], shape=(refs, d))
    scales = []
    for i in range(0, refs, 2048):
        block = rng.normal(size=(min(2048, refs - i), d)).astype(np.float32)
        block /= np.linalg.norm(block, axis=1, keepdims=True)
        enc = Encodings.pack(block, storage)
        values[i:i + len(block)] = enc.values
        if enc.scale is not None:
            scales.append(enc.scale)
    stored = Encodings(values, storage, np.concatenate(scales) if scales else None)
    save_map(PlaceMap(stored, [f"{i:06d}.jpg" for i in range(refs)], real.encoder, dict(real.meta)), out, storage)
    del values


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--map", type=Path, required=True, help="a real map (its encoder sets the encoding size)")
    p.add_argument("--refs", default="1000,10000,100000")
    p.add_argument("--storage", default="int8")
    p.add_argument("--out", type=Path, default=None, help="folder for the synthetic maps (default: a temp dir)")
    a = p.parse_args()
    real = load_map(a.map)
    with tempfile.TemporaryDirectory(prefix="vpr-bench-") as tmp:
        folder = a.out or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        print(f"encodings of {real.stored.shape[1]} dims stored as {a.storage}; one query row per similarity")
        print(f"{'refs':>8s} {'file MB':>9s} {'open':>5s} {'open s':>8s} {'RSS MB':>8s} {'cold ms':>9s} "
              f"{'warm ms':>9s} {'RSS after':>9s}")
        for refs in (int(r) for r in a.refs.split(",")):
            path = folder / f"bench_{refs}.map.npz"
            t0 = time.perf_counter()
            synthetic_map(real, refs, a.storage, path, Path(tmp))
            made = time.perf_counter() - t0
            for how in ("mmap", "ram"):
                proc = subprocess.run([sys.executable, "-c", PROBE, str(path), how], capture_output=True,
                                      text=True, check=True)
                r = json.loads(proc.stdout)
                print(f"{refs:8d} {path.stat().st_size / 1e6:9.1f} {how:>5s} {r['open_s']:8.3f} "
                      f"{r['rss_open_mb']:8.1f} {r['cold_ms']:9.1f} {r['warm_ms']:9.1f} {r['rss_after_mb']:9.1f}",
                      flush=True)
            print(f"{'':8s} (written in {made:.1f} s)")
            path.unlink()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
