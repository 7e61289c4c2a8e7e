"""What an online matcher's frame reads from a map: the similarities it asks for and, on a map with an index,
the index's candidates; one policy for ``Localizer`` (frame by frame) and ``evaluate`` (over a stream), so
that ``evaluate`` measures what ``localize`` answers, index and coarse whole-route search included.

A frame's matcher update (``matchers.step``) asks for the references its search needs (``wanted()``: a
window around a firm lock, or the whole route). On a map with an index (``index.ivf``) a whole-route frame
searches around the index's candidates for the mean of the last ``seek_frames`` encodings
(``index.ivf.SequenceQuery``); on a long map (``COARSE_MIN_REFS`` places or more, ``index.coarse``) a
whole-route row is the coarse one: exact at the sign-ranked best references, estimated elsewhere. Every
other row is exact.
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

from vpr_edge.encoders.standardise import STANDARDISE, StreamMean
from vpr_edge.index.coarse import COARSE_MIN_REFS, CoarseSearch
from vpr_edge.index.ivf import SequenceQuery
from vpr_edge.map.query import MapQuery

Rows = Callable[[np.ndarray | None], np.ndarray]   # references (None: all) -> the frame's similarities to them


def uses_coarse(n_refs: int, coarse: bool | None, kind: str, searches_locally: bool) -> bool:
    """Whether whole-route rows are coarse: asked (``coarse``; None: on maps of ``COARSE_MIN_REFS`` places or
    more), for cosine similarities and a matcher that searches locally (its other frames read exact rows)."""
    wanted = n_refs >= COARSE_MIN_REFS if coarse is None else coarse
    return bool(wanted) and kind == "cosine" and searches_locally


def coarse_search(query: MapQuery, wanted: bool) -> CoarseSearch | None:
    """The coarse whole-route search of ``query``'s map where ``wanted`` (``uses_coarse``), else None; one
    serves every stream and mode on the map (its signs are packed once, on first use)."""
    return CoarseSearch(query.map.stored) if wanted else None


class FrameSearch:
    """The search inputs of one stream's frames on ``query``'s map, for a matcher comparing ``kind`` scores
    (``cosine`` or ``svm``) whose index query is the mean of ``seek_frames`` encodings; ``coarse``: the coarse
    search whole-route rows come from (``coarse_search``; None: exact rows); ``standardise``: cosines of the
    standardised encodings (``encoders.standardise``: each frame centred on the stream's running mean, the
    references on theirs; the index and the coarse search are asked with the centred encoding).
    ``push(encoding)`` for each frame in order, then ``rows`` and ``candidates`` are that frame's."""

    def __init__(self, query: MapQuery, kind: str, seek_frames: int, coarse: CoarseSearch | None,
                 standardise: bool = STANDARDISE) -> None:
        self.query, self.kind = query, kind
        self.index = query.map.index if kind == "cosine" else None
        self.coarse = coarse
        self.mean = StreamMean(query.map.route_mean.mean) if standardise and kind == "cosine" else None
        self._seq = SequenceQuery(seek_frames)
        self._enc: np.ndarray | None = None
        self._exact: Rows | None = None

    def push(self, encoding: np.ndarray, exact: Rows | None = None) -> None:
        """The next frame's encoding (D,); ``exact``: its exact rows if already computed (a whole stream's
        similarity matrix, ``evaluate``, standardised as here; None: computed from the map when asked)."""
        enc = np.asarray(encoding, np.float32)
        self._enc = enc if self.mean is None else self.mean.centre(enc)
        self._exact = exact
        self._seq.push(self._enc)

    def rows(self, refs: np.ndarray | None) -> np.ndarray:
        """The frame's similarities to the references ``refs`` (sorted int array; None: every one, coarse on a
        long map)."""
        if self._exact is not None and (refs is not None or self.coarse is None):
            return self._exact(refs)
        dots = self.coarse.similarity(self._enc)[None] if refs is None and self.coarse is not None else \
            self.query.scores(self._enc[None], self.kind, refs)
        if self.mean is None:
            return dots[0]
        return self.query.map.route_mean.scores(dots, self._enc[None], refs)[0]

    def candidates(self) -> Callable[[], np.ndarray] | None:
        """What ``matchers.step`` asks the index, for this frame (None: the map has no index)."""
        if self.index is None:
            return None
        index, stored, seq = self.index, self.query.map.stored, self._seq
        return lambda: index.candidates(stored, seq.query())

    def reset(self) -> None:
        """Forget the stream (the index's sequence query, the stream's mean)."""
        self._seq.reset()
        if self.mean is not None:
            self.mean.reset()


class StreamSearch:
    """``FrameSearch`` over a whole stream: the query ``encodings`` (Q, D) and their exact rows ``sim`` (Q, R),
    frame ``i``'s rows and candidates on demand, in order (``matchers.run_rows``)."""

    def __init__(self, search: FrameSearch, encodings: np.ndarray, sim: np.ndarray) -> None:
        self.search, self.encodings, self.sim = search, encodings, sim
        self._at = -1

    def _frame(self, i: int) -> None:
        if i != self._at:
            if i != self._at + 1:
                raise ValueError(f"frames are searched in order: frame {i} after {self._at}")
            sim = self.sim[i]
            self.search.push(self.encodings[i], lambda refs: sim if refs is None else sim[refs])
            self._at = i

    def rows(self, i: int, refs: np.ndarray | None) -> np.ndarray:
        self._frame(i)
        return self.search.rows(refs)

    def candidates(self, i: int) -> Callable[[], np.ndarray] | None:
        self._frame(i)
        return self.search.candidates()
