"""Descriptor standardisation: each traversal's own mean encoding taken away before the cosine.

What a whole drive has in common (the season, the light, the camera's colour) lies in every encoding of it
and makes places look alike. Taking away the references' mean from each reference, and a running mean of
the query stream from each query, leaves what tells places apart (Schubert, Neubert and Protzel, ICRA 2020).
The stream's mean starts from the references' mean, weighted as ``PRIOR_FRAMES`` frames, so the first frame
already works; frames then count with an exponential memory of ``HORIZON`` frames, which follows a drive from
day into dusk.

The map keeps its encodings as they are: the cosine of the standardised pair is computed from the stored
rows, the references' mean (D,) and each reference's distance from it (R,):

    cos(r - m_r, q - m_q) = (r . q' - m_r . q') / (|r - m_r| |q'|),   q' = q / |q| - m_q

so int8 rows, memory-mapped maps and the index work unchanged (the index is asked with ``q'``).
"""
from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from vpr_edge.encoders.base import unit_rows

STANDARDISE = True    # localize, Localizer and evaluate standardise unless told not to (--raw-cosines)
PRIOR_FRAMES = 10.0   # the references' mean counts as this many of the stream's frames
HORIZON = 1000.0      # frames of the stream's running mean (an exponential memory)
MIN_SPREAD = 1e-6     # the smallest distance of a reference from the mean divided by (a reference at the mean)


@dataclass(frozen=True)
class RouteMean:
    """The references' statistics: ``mean`` (D,) float32, the mean of their unit encodings, and ``spread``
    (R,) float32, each unit reference's distance from it."""

    mean: np.ndarray
    spread: np.ndarray

    @classmethod
    def of(cls, blocks: Callable[[], Iterable[np.ndarray]]) -> "RouteMean":
        """From the stored references in route order: ``blocks()`` yields them a block (n, D) at a time, rows
        of any positive scale (each is made unit first); read twice, never held whole."""
        total, n = None, 0
        for b in blocks():
            u = unit_rows(b)
            total = u.sum(axis=0) if total is None else total + u.sum(axis=0)
            n += len(u)
        if total is None or n == 0:
            raise ValueError("no references to take a mean over")
        mean = total / n
        spread = np.concatenate([np.linalg.norm(unit_rows(b) - mean, axis=1) for b in blocks()])
        return cls(mean.astype(np.float32), np.maximum(spread, MIN_SPREAD).astype(np.float32))

    def scores(self, dots: np.ndarray, centred: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """The standardised cosines (B, n) from ``dots`` (B, n), each stored reference's dot product with the
        centred queries ``centred`` (B, D) (``q / |q| - m_q``), of the references ``rows`` (None: all)."""
        c = np.atleast_2d(np.asarray(centred, np.float32))
        norm = np.maximum(np.linalg.norm(c, axis=1), MIN_SPREAD)
        spread = self.spread if rows is None else self.spread[np.asarray(rows, np.int64).reshape(-1)]
        return ((dots - (c @ self.mean)[:, None]) / (norm[:, None] * spread[None, :])).astype(np.float32)


class StreamMean:
    """The running mean of a query stream's unit encodings (module docstring): ``centre(q)`` gives
    ``q / |q| - mean`` with the mean of the frames before it (and the prior), then counts ``q``."""

    def __init__(self, prior: np.ndarray, prior_frames: float = PRIOR_FRAMES, horizon: float = HORIZON) -> None:
        if prior_frames <= 0 or horizon < 1:
            raise ValueError(f"need prior_frames > 0 and horizon >= 1, got {prior_frames}, {horizon}")
        self.prior, self.prior_frames, self.keep = np.asarray(prior, np.float64), prior_frames, 1.0 - 1.0 / horizon
        self.reset()

    def reset(self) -> None:
        """Forget the stream: the mean is the prior's."""
        self._sum = self.prior * self.prior_frames
        self._weight = self.prior_frames

    @property
    def mean(self) -> np.ndarray:
        """The current mean (D,) float64."""
        return self._sum / self._weight

    def centre(self, encoding: np.ndarray) -> np.ndarray:
        """One encoding (D,) -> ``unit(encoding) - mean`` (D,) float32; the encoding then joins the mean (an
        all-zero encoding does not)."""
        u = unit_rows(np.asarray(encoding, np.float64)[None])[0]
        out = (u - self.mean).astype(np.float32)
        if np.any(u):
            self._sum = self._sum * self.keep + u
            self._weight = self._weight * self.keep + 1.0
        return out


def centred_stream(encodings: np.ndarray, prior: np.ndarray, prior_frames: float = PRIOR_FRAMES,
                   horizon: float = HORIZON) -> np.ndarray:
    """A stream's encodings (Q, D) in order -> each centred on the running mean before it (Q, D) float32
    (``StreamMean`` frame by frame)."""
    mean = StreamMean(prior, prior_frames, horizon)
    if not len(encodings):
        return np.zeros((0, len(prior)), np.float32)
    return np.stack([mean.centre(e) for e in np.asarray(encodings)])
