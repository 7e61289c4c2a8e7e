"""The motion cue: whether the camera stands, read from the query stream itself, relative to how much its
frames change while it moves.

A camera that stands sees the same view again, but a real camera's next frame is a new exposure (sensor
noise, a flicker of light, a fraction of a pixel of vibration), so its encoding is alike the last one, not
equal to it; how alike depends on the camera, the front end and the scenery. A moving camera's consecutive
frames differ by a step that also depends on them (the frame rate, the speed, how alike the places look).
So the cue is relative: a frame's distance from the *anchor* (the last frame that moved), ``d = 1 - cosine``
of their encodings, against the typical step of this stream's moving frames (the median ``d`` of the last
``memory`` frames that moved):

    cue = 1 - d / typical_step          (1: the same view again; 0: as far as a typical moving step)

A frame *stands* when its cue is at least the matcher's threshold ``still`` (0.5: it differs from the
anchor by at most half a typical moving step). A standing frame keeps the anchor and adds nothing to the
moving steps, so a stop of any length is judged against the steps of the motion before it; a camera creeping
by steps too small to tell apart still shows motion once it has crept far enough from the anchor, and its
steps then set the typical step.

Until ``MIN_STEPS`` moving frames have been seen there is no typical step of the stream's own, and those
first frames are taken as moving steps (cue 0), whatever they show. A frame whose encoding is its anchor's,
bit for bit (within ``REPEAT_STEP``: a duplicated frame), is the same view again whenever it comes: cue 1, no
step. No step in cosine units is fixed in the
code: a front end whose cosines all lie in 0.999-1.0 (a network with random weights) and one whose cosines
spread over 0-1 are each read on their own scale. (A fixed first step of 0.02 once read every frame of the
first as standing, so nothing was ever followed. The map's own moving step as the first one was tried too: a
stream whose frames all look alike to that front end, imagery of somewhere else, then stood for ever.) A
stream that starts standing reads its first frames as motion, and its stop then as a mix of both, until the
median of its moving steps is motion's.

``route_stands`` reads the same cue along the map's references (the mapping drive's own stops: references
that show one view, e.g. a train standing at a station).
"""
from __future__ import annotations

from bisect import bisect_left, insort
from collections import deque
from collections.abc import Iterable

import numpy as np

from vpr_edge.matchers.constants import MEMORY, MIN_STEPS, REPEAT_STEP


def stands(still: float | None, threshold: float | None) -> bool:
    """Whether a frame with motion cue ``still`` shows a standing camera for a matcher whose ``still``
    parameter is ``threshold`` (None or 0: the cue is not used, nothing stands)."""
    return still is not None and bool(threshold) and still >= threshold


class _Steps:
    """The last ``memory`` moving steps and their median, kept sorted (O(memory) a frame, no array calls)."""

    def __init__(self, memory: int) -> None:
        self.memory = memory
        self._order: deque[float] = deque()
        self._sorted: list[float] = []

    def add(self, d: float) -> None:
        if len(self._order) == self.memory:
            del self._sorted[bisect_left(self._sorted, self._order.popleft())]
        self._order.append(d)
        insort(self._sorted, d)

    def typical(self) -> float | None:
        """The median step (None until ``MIN_STEPS`` steps, or ``memory`` if fewer)."""
        n = len(self._sorted)
        if n < min(MIN_STEPS, self.memory):
            return None
        mid = n // 2
        median = self._sorted[mid] if n % 2 else 0.5 * (self._sorted[mid - 1] + self._sorted[mid])
        return max(median, 1e-12)

    def clear(self) -> None:
        self._order.clear()
        self._sorted.clear()


class MotionCue:
    """The motion cue of a stream, frame by frame (module docstring): each encoding's distance from the anchor
    (the last frame that did not stand by ``threshold``; None: no frame stands, the anchor is always the
    previous frame) relative to the median step of the last ``memory`` frames that moved (before ``MIN_STEPS``
    of them, a frame moves, cue 0). None for the first frame and next to an all-zero encoding (such a frame
    becomes the anchor and adds no step). What ``Localizer`` runs per frame, ``stillness`` over a whole stream
    and ``route_stands`` along a map."""

    def __init__(self, threshold: float | None = None, memory: int = MEMORY) -> None:
        if memory < 1:
            raise ValueError(f"the motion cue's memory must be at least 1 frame, got {memory}")
        self.threshold, self.memory = threshold, int(memory)
        self._anchor: np.ndarray | None = None
        self._norm = 0.0
        self._steps = _Steps(self.memory)

    def typical_step(self) -> float | None:
        """The median distance (1 - cosine) between a moving frame and its anchor, over the last ``memory``
        moving frames (None until ``MIN_STEPS`` of them, or ``memory`` if fewer)."""
        return self._steps.typical()

    def judge(self, d: float) -> tuple[float, bool]:
        """A frame at distance ``d`` (1 - cosine) from the anchor -> (its cue, whether it stands); a frame
        that does not stand adds its step (the caller makes it the anchor). Without a typical step yet (fewer
        than ``MIN_STEPS`` moving frames): cue 0, a moving step."""
        if d <= REPEAT_STEP:   # the anchor's encoding again, bit for bit (a duplicated frame): no step
            return 1.0, stands(1.0, self.threshold)
        typical = self.typical_step()
        if typical is None:
            self._steps.add(d)
            return 0.0, False
        still = 1.0 - d / typical
        standing = stands(still, self.threshold)
        if not standing:
            self._steps.add(d)
        return still, standing

    def __call__(self, encoding: np.ndarray) -> float | None:
        """The next frame's encoding (D,) -> its cue (1 = the same view again, 0 = a typical moving step;
        None: none)."""
        enc = np.asarray(encoding, np.float64)
        norm = float(np.linalg.norm(enc))
        if self._anchor is None or norm == 0 or self._norm == 0:
            self._anchor, self._norm = enc, norm
            return None
        still, standing = self.judge(1.0 - float(enc @ self._anchor) / (norm * self._norm))
        if not standing:
            self._anchor, self._norm = enc, norm
        return still

    def reset(self) -> None:
        """Forget the stream."""
        self._anchor, self._norm = None, 0.0
        self._steps.clear()


def stillness(encodings: Iterable[np.ndarray], threshold: float | None = None, memory: int = MEMORY) -> np.ndarray:
    """Encodings (Q, D) of consecutive frames -> each frame's motion cue (Q,) float64 (``MotionCue`` with
    ``threshold`` and ``memory``), NaN where there is none."""
    cue = MotionCue(threshold, memory)
    return np.array([np.nan if (c := cue(e)) is None else c for e in encodings], np.float64)


def route_stands(blocks: Iterable[np.ndarray], threshold: float, memory: int = MEMORY) -> np.ndarray:
    """The map's references in route order, as consecutive blocks (n, D) -> (R,) bool: True where a reference
    stands by the motion cue (``MotionCue`` over the references: it shows the view of the last one that
    moved, the mapping drive stood there). Consecutive cosines are computed a block at a time; the decisions
    (``MotionCue.judge``) run over plain floats, and only a standing stretch compares with its anchor row by
    row."""
    cue = MotionCue(threshold, memory)
    out: list[np.ndarray] = []
    anchor: np.ndarray | None = None      # unit row of the anchor, when it is not the previous row
    prev: np.ndarray | None = None        # unit previous row (zero row: None)
    for block in blocks:
        x = np.asarray(block, np.float64)
        norm = np.linalg.norm(x, axis=1)
        unit = np.divide(x, norm[:, None], out=np.zeros_like(x), where=norm[:, None] > 0)
        lead = unit[:1] if prev is None else prev[None]
        cos = np.einsum("ij,ij->i", unit, np.concatenate([lead, unit[:-1]])).tolist()
        zero = (norm == 0).tolist()
        flags = [False] * len(x)
        have_prev = prev is not None
        for i in range(len(x)):
            if zero[i] or not (have_prev or anchor is not None):
                anchor, have_prev = None, not zero[i]      # no cue: this row becomes the anchor
                continue
            _, flags[i] = cue.judge(1.0 - (cos[i] if anchor is None else float(unit[i] @ anchor)))
            if not flags[i]:
                anchor = None
            elif anchor is None:
                anchor = unit[i - 1] if i else prev
            have_prev = True
        prev = unit[-1] if len(x) and not zero[-1] else None
        out.append(np.array(flags, bool))
    return np.concatenate(out) if out else np.zeros(0, bool)


def cue_at(still: np.ndarray | None, i: int) -> float | None:
    """Frame ``i``'s motion cue from a (Q,) array of them (``stillness``; NaN or no array: None)."""
    if still is None or not np.isfinite(still[i]):
        return None
    return float(still[i])
