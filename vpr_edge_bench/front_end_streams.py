"""One query stream through one front end, and what ``front-end-cache`` keeps of it: its encodings and (Q, R)
similarities (``sources.from_map``, or ``sources.from_pixels`` for ``pixels``, as ``evaluate``), padded truth,
the ``single`` matcher's R@1, the ``stream`` matcher's motion cue, route and reach (``record``); and the
``noisy`` front end: ``ifv``'s encodings with seeded Gaussian noise, its deviation calibrated (``ensure_noise``).
"""
from __future__ import annotations

import os
import sys
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vpr_edge.encoders.standardise import RouteMean, centred_stream
from vpr_edge.evaluation import sources
from vpr_edge.evaluation.run import check_truth_fits, map_same_view
from vpr_edge.evaluation.scoring import evaluate_mode
from vpr_edge.evaluation.truth import Truth, one_view
from vpr_edge.frames.frame import Frame
from vpr_edge.frames.images import list_images
from vpr_edge.map import MapQuery
from vpr_edge.matchers import get_matcher
from vpr_edge_bench.folder import StreamsFolder

FOREIGN = "foreign"   # the name of the stream of the next dataset's frames (none mapped)


@dataclass(frozen=True)
class Stream:
    """One query stream: its ``name`` (a stream kind, or ``foreign``), its frame folder and its ground-truth
    CSV (None: foreign, no frame shows a mapped place)."""

    name: str
    frames: Path
    gt: Path | None

    def truth_name(self) -> str:
        """What error messages call the stream's truth: its CSV, or its frames marked foreign."""
        return str(self.gt) if self.gt is not None else f"{self.frames} (foreign: unmapped)"


@dataclass
class Encoded:
    """A stream as a front end sees it: the query encodings (Q, D) of its decoded frames (None: pixels), their
    (Q, R) similarities to the references, and their padded truth rows."""

    encodings: np.ndarray | None
    sim: np.ndarray
    truth: np.ndarray


def streams_of(folder: StreamsFolder, other: StreamsFolder | None) -> list[Stream]:
    """Every derived stream of ``folder``, then the foreign one (``other``'s aligned frames) if given."""
    out = [Stream(k, folder.frames(k), folder.truth(k)) for k in folder.kinds]
    if other is not None:
        out.append(Stream(FOREIGN, other.frames("aligned"), None))
    return out


def save_npz(path: Path, arrays: dict[str, np.ndarray | float | int]) -> None:
    """``np.savez`` written atomically (a run stopped midway leaves no file that a rerun would keep)."""
    tmp = path.with_name(f".{path.stem}.tmp.npz")
    np.savez(tmp, **{k: np.asarray(v) for k, v in arrays.items()})
    os.replace(tmp, path)


def frame_count(stream: Stream) -> int:
    """How many images the stream's frame folder holds."""
    return len(list_images(stream.frames))


def load_truth(stream: Stream, query: MapQuery | None) -> np.ndarray:
    """The stream's padded truth as ``evaluate`` reads it (with the map's positions and labels), or all -1."""
    if stream.gt is None:
        return np.full((frame_count(stream), 1), -1, np.int64)
    rows, _ = Truth(gt=stream.gt).load(None if query is None else query.map.positions,
                                       None if query is None else query.map.labels)
    return rows


def skip_warning(frame: Frame) -> None:
    """Say on stderr that ``frame`` was skipped (not decodable), as ``evaluate`` does."""
    print(f"warning: skipped frame {frame.name} (not decodable)", file=sys.stderr)


def kept_rows(sims: sources.Similarities, truth: np.ndarray, stream: Stream) -> np.ndarray:
    """``truth``'s rows of the frames that decoded, checked against the matrix as ``evaluate`` does."""
    rows = truth if sims.kept is None else truth[sims.kept]
    check_truth_fits(rows, None, sims.cosine, stream.truth_name())
    return rows


def encode_map(query: MapQuery, stream: Stream) -> Encoded:
    """``stream`` through ``query``'s chain (``sources.from_map``, as ``evaluate --raw-cosines``): the plain
    cosines, whatever ``evaluate``'s default (``record`` standardises them when asked)."""
    truth = load_truth(stream, query)
    sims = sources.from_map(query, stream.frames, len(truth), stream.truth_name(), skip_warning, standardise=False)
    return Encoded(sims.encodings, sims.cosine, kept_rows(sims, truth, stream))


def encode_pixels(refs: Path, stream: Stream) -> Encoded:
    """``stream`` against ``refs`` by SeqSLAM's pixel front end (``sources.from_pixels``, as ``evaluate``)."""
    truth = load_truth(stream, None)
    sims = sources.from_pixels(refs, stream.frames, len(truth), stream.truth_name(), skip_warning)
    return Encoded(None, sims.cosine, kept_rows(sims, truth, stream))


def single_r1(sim: np.ndarray, truth: np.ndarray, tolerance: int = 0) -> float:
    """The ``single`` matcher's recall@1 within ``tolerance`` references (NaN when no frame is mapped)."""
    if not (truth >= 0).any():
        return float("nan")
    return float(evaluate_mode(get_matcher("single"), sim, truth, tolerance=tolerance).recall[1])


def single_figures(sim: np.ndarray, truth: np.ndarray, tolerance: int) -> dict[str, np.float64]:
    """A cached stream's front end alone: ``single``'s R@1 exactly and within ``tolerance`` (the cache's keys)."""
    exact, within = single_r1(sim, truth), single_r1(sim, truth, tolerance)
    return {"single_r1": np.float64(exact), "single_r1_tol": np.float64(within)}


def unit(x: np.ndarray) -> np.ndarray:
    """Rows scaled to unit length (zero rows left zero), float32."""
    x = np.asarray(x, np.float32)
    n = np.linalg.norm(x, axis=1, keepdims=True)
    return np.divide(x, n, out=np.zeros_like(x), where=n > 0)


def standardised(encodings: np.ndarray, references: list[np.ndarray]) -> np.ndarray:
    """A stream's encodings (Q, D) against the map's stored rows in route order (blocks, any positive row
    scale) -> the cosines of the standardised pairs (Q, R) float32, as ``vpr-edge evaluate --standardise``."""
    route = RouteMean.of(lambda: iter(references))
    centred = centred_stream(encodings, route.mean)
    refs = unit(np.concatenate([np.asarray(b, np.float32) for b in references]))
    return route.scores(centred @ refs.T, centred)


def record(enc: Encoded, references: list[np.ndarray] | None, tolerance: int, standardise: bool = False
           ) -> dict[str, np.ndarray | float | int]:
    """What a stream's file holds: the matrix and truth, the single matcher's R@1 (at tolerance 0 and at
    ``tolerance``), and with ``references`` (the map's encodings in route order, as blocks) the motion cue,
    route, reach and one-view frames; ``standardise``: the matrix of standardised cosines (``standardised``;
    a front end without encodings, pixels, keeps its own)."""
    if standardise and references is not None and enc.encodings is not None:
        enc = Encoded(enc.encodings, standardised(enc.encodings, references).astype(np.float64), enc.truth)
    out: dict[str, np.ndarray | float | int] = {
        "sim": enc.sim.astype(np.float32), "truth": enc.truth, **single_figures(enc.sim, enc.truth, tolerance),
        "tolerance": tolerance}
    if references is not None and enc.encodings is not None:
        stream = get_matcher("stream")
        on = stream.on_route(iter(references), None)
        out["cue"] = stream.cue(enc.encodings)
        if on.route is not None:
            out["route"] = np.asarray(on.route, bool)
        out["reach"] = int(on.reach)
        out["one_view"] = one_view(enc.truth, map_same_view(iter(references)))
    return out


# --- noisy ----------------------------------------------------------------------------------------------------

def noise_rng(seed: int, name: str) -> np.random.Generator:
    """A generator seeded by ``seed`` and a name (the references, or a stream): reproducible per stream."""
    return np.random.default_rng([seed, zlib.crc32(name.encode())])


def noisy(x: np.ndarray, std: float, z: np.ndarray) -> np.ndarray:
    """Unit rows of ``x`` plus ``std`` times the standard normal draws ``z``, back to unit length."""
    return unit(unit(x) + std * z)


@dataclass
class Noise:
    """``ifv``'s encodings with Gaussian noise: the deviation ``std`` (per dimension, on unit encodings),
    the noisy references (R, D) and the seed of the query draws."""

    std: float
    references: np.ndarray
    seed: int

    def apply(self, enc: Encoded, name: str) -> Encoded:
        """The stream ``enc`` (``ifv``'s) with noisy queries, its cosines to the noisy references."""
        z = noise_rng(self.seed, name).standard_normal(enc.encodings.shape).astype(np.float32)
        q = noisy(enc.encodings, self.std, z)
        return Encoded(q, (q @ self.references.T).astype(np.float64), enc.truth)


def calibrate_noise(refs: np.ndarray, aligned: Encoded, seed: int, target: float, fraction: float,
                    tolerance: int, steps: int = 30) -> tuple[float, float, float]:
    """(deviation, R@1 without noise, R@1 aimed at): the per-dimension deviation (bisected on a log scale,
    draws fixed) at which ``single``'s R@1 within ``tolerance`` on the aligned stream is closest to ``target``,
    or to ``fraction`` of the R@1 without noise where that is lower (noise cannot raise it)."""
    zr = noise_rng(seed, "references").standard_normal(refs.shape).astype(np.float32)
    zq = noise_rng(seed, "aligned").standard_normal(aligned.encodings.shape).astype(np.float32)

    def r1(std: float) -> float:
        sim = (noisy(aligned.encodings, std, zq) @ noisy(refs, std, zr).T).astype(np.float64)
        return single_r1(sim, aligned.truth, tolerance)

    clean = r1(0.0)
    target = min(target, fraction * clean)
    lo, hi = 1e-4, 1.0   # per dimension, on unit vectors of D dims: noise length std * sqrt(D)
    best = (abs(r1(hi) - target), hi)
    for _ in range(steps):
        mid = float(np.sqrt(lo * hi))
        got = r1(mid)
        best = min(best, (abs(got - target), mid))
        if abs(got - target) < 0.01:
            break
        lo, hi = (mid, hi) if got > target else (lo, mid)
    return best[1], clean, target


def ensure_noise(path: Path, refs: np.ndarray, aligned: Callable[[], Encoded], seed: int, target: float,
                 fraction: float, tolerance: int) -> Noise:
    """The noisy references and deviation kept in ``path`` (noise.npz), calibrated and written if absent."""
    if path.is_file():
        with np.load(path, allow_pickle=False) as f:
            return Noise(float(f["std"]), f["references"], int(f["seed"]))
    std, clean, target = calibrate_noise(refs, aligned(), seed, target, fraction, tolerance)
    zr = noise_rng(seed, "references").standard_normal(refs.shape).astype(np.float32)
    noise = Noise(std, noisy(refs, std, zr), seed)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_npz(path, {"std": std, "references": noise.references, "seed": seed, "target_r1": target,
                    "clean_r1": clean, "tolerance": tolerance})
    print(f"{path}: noise std {std:.4g} a dimension (length {std * np.sqrt(refs.shape[1]):.3g} on unit "
          f"encodings of {refs.shape[1]} dims), aiming at single R@1 {target:.3f} within {tolerance} (ifv's "
          f"own {clean:.3f})", flush=True)
    return noise

