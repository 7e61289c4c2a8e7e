"""Per-frame cost of localize's file outputs: -o run.csv, -o run.mcap, --rerun run.rrd, with and without flushing.

    python -m vpr_edge_bench bench-outputs [--map MAP] [--stream DIR] [--frames N] [--repeat R] [--threads 1]

Each row is ``localize``'s own stream loop, timed per frame: frames read from --stream (default the bundled
sample's queries, cycled to N frames), matched and written to the sinks the CLI builds (``result_sinks``):
``csv`` (-o run.csv), ``mcap`` (-o run.mcap), ``rrd`` (--rerun run.rrd beside -o run.csv). The ``-unflushed``
rows stop the recording's flushing thread (``part.Flusher``) after opening: what writing costs without
handing records to the system as the stream goes. Rows run in turn, R rounds, the order rotated each round;
a row's figure is its median over rounds; ratios are to ``csv`` of the same rounds. Without --map, one is
built from the sample's references with build-map's defaults (not timed).
"""
from __future__ import annotations

import itertools
import statistics
import tempfile
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

from vpr_edge import Localizer
from vpr_edge.frames.frame import Frame
from vpr_edge.frames.images import list_images, load_image
from vpr_edge.map.make import BuildOptions, plan_map, write_map
from vpr_edge.resources import sample_folder
from vpr_edge_bench.runner import parser, run_checked

ROWS = ("csv", "mcap", "mcap-unflushed", "rrd", "rrd-unflushed")


def cycled(files: list[Path], n: int) -> Iterator[Frame]:
    """``n`` frames read from ``files`` in turn (as the CLI's folder stream reads them), 0.1 s apart."""
    for i, path in zip(range(n), itertools.cycle(files)):
        yield Frame(i, path.name, load_image(path), stamp=0.1 * i)


def one_run(loc: Localizer, map_path: Path, stream: Path, files: list[Path], n: int, row: str, tmp: Path) -> float:
    """Seconds per frame of one stream of ``n`` frames written to ``row``'s outputs in ``tmp``."""
    from vpr_edge.cli.localize import result_sinks

    kind = row.split("-")[0]
    out = tmp / ("run.mcap" if kind == "mcap" else "run.csv")
    record = tmp / "run.rrd" if kind == "rrd" else None
    loc.reset()
    sinks, _ = result_sinks(loc, map_path, str(stream), out, "csv", False, record)
    if row.endswith("-unflushed"):
        for sink in sinks:
            flusher = getattr(sink, "_flusher", None)
            if flusher is not None:
                flusher.stop()
    start = time.perf_counter()
    for frame, match in loc.answers(cycled(files, n)):
        for sink in sinks:
            sink.write(match, frame)
    for sink in sinks:
        sink.close(True)
    return (time.perf_counter() - start) / n


def main(argv: Sequence[str] | None = None) -> int:
    p = parser(__name__, __doc__)
    p.add_argument("--map", type=Path, default=None)
    p.add_argument("--stream", type=Path, default=sample_folder() / "query", help="folder of frames")
    p.add_argument("--frames", type=int, default=333, help="frames per run (the folder cycled)")
    p.add_argument("--repeat", type=int, default=5, help="rounds of every row")
    p.add_argument("--threads", type=int, default=1, help="onnxruntime and BLAS threads")
    a = p.parse_args(argv)
    if a.frames < 1 or a.repeat < 1:
        p.error("--frames and --repeat must be >= 1")
    return run_checked(__name__, lambda: _bench(a))


def _bench(a) -> int:
    with tempfile.TemporaryDirectory(prefix="vpr-edge-bench-") as name:
        tmp = Path(name)
        map_path = a.map
        if map_path is None:
            map_path = tmp / "sample.map.npz"
            write_map(plan_map(sample_folder() / "ref", map_path, BuildOptions()))
        files = list_images(a.stream)
        loc = Localizer(map_path, threads=a.threads)
        one_run(loc, map_path, a.stream, files, min(a.frames, 20), "csv", tmp)      # warm-up
        times: dict[str, list[float]] = {row: [] for row in ROWS}
        for r in range(a.repeat):
            order = ROWS[r % len(ROWS):] + ROWS[:r % len(ROWS)]
            for row in order:
                times[row].append(one_run(loc, map_path, a.stream, files, a.frames, row, tmp))
        print(f"{a.frames} frames a run from {a.stream}, {a.repeat} rounds, --threads {a.threads}; "
              f"map {len(loc.names)} places")
        print(f"{'output':<15s} {'ms/frame':>9s} {'min':>7s} {'max':>7s} {'ratio':>6s}")
        for row in ROWS:
            ms = [1e3 * t for t in times[row]]
            print(f"{row:<15s} {statistics.median(ms):9.3f} {min(ms):7.3f} {max(ms):7.3f} "
                  f"{_ratio(times[row], times['csv']):6.3f}")
        for kind in ("mcap", "rrd"):
            print(f"flushing {kind}: {_ratio(times[kind], times[kind + '-unflushed']):.3f} x its cost unflushed")
    return 0


def _ratio(times: list[float], base: list[float]) -> float:
    """The median of the rounds' ratios ``times / base`` (each round's two rows beside each other)."""
    return statistics.median(t / b for t, b in zip(times, base))
