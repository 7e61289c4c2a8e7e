"""How a stream went, counted as its answers come: frames answered and lost (by ``Match.lost_why``), the
frame rate, and the early warning that a stream does not fit its map, said only when matching suffers: many
frames lost over the first stretch (with their size, when it is far from the references'). Pure: no I/O, no
clock (the caller gives the wall time)."""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

from vpr_edge.errors import said
from vpr_edge.api import Match
from vpr_edge.frames.frame import Frame

FIRST_STRETCH = 50   # frames: the first stretch of a stream judged for the "does not fit" warning
LOST_SHARE = 0.9     # share of that stretch lost that says the stream hardly fits the map
SIZE_LOST_SHARE = 0.5   # ... that says frames far from the references' size cost answers (a fair size: nothing)
SIZE_FACTOR = 2.0    # a frame side more than this many times the references' (or less than a part): no fit
ASPECT_FACTOR = 1.3  # aspect ratios further apart than this (4:3 against 16:9 is 1.33): another camera
UNSAID = "no reason given"   # a lost frame whose matcher names no reason (lost_why None)


def size_misfit(frame: tuple[int, int], refs: tuple[int, int]) -> bool:
    """Whether frames of ``frame`` (width, height) pixels are far from references of ``refs``: a side more
    than ``SIZE_FACTOR`` times the other's, either way, or aspect ratios more than ``ASPECT_FACTOR`` apart."""
    ratios = (frame[0] / refs[0], frame[1] / refs[1])
    far = any(r > SIZE_FACTOR or r < 1 / SIZE_FACTOR for r in ratios)
    aspect = ratios[0] / ratios[1]
    return far or aspect > ASPECT_FACTOR or aspect < 1 / ASPECT_FACTOR


@dataclass
class RunSummary:
    """Counts of one stream. ``ref_size``: the map's reference images' (width, height) in pixels, if it
    records them. ``add`` each answer (with its frame), ``skip`` each undecodable frame; ``lines`` says it."""

    ref_size: tuple[int, int] | None = None
    answered: int = 0
    lost: Counter = field(default_factory=Counter)   # lost_why (or UNSAID) -> frames
    skipped: int = 0
    frame_size: tuple[int, int] | None = None        # the first frame's (width, height)
    warned: set = field(default_factory=set)

    @property
    def frames(self) -> int:
        """Frames answered or lost (undecodable ones not counted)."""
        return self.answered + sum(self.lost.values())

    def skip(self) -> None:
        self.skipped += 1

    def add(self, match: Match, frame: Frame | None = None) -> list[str]:
        """Count ``match``; return the warning this frame makes due (said once, after the first
        ``FIRST_STRETCH`` frames): ``LOST_SHARE`` of them lost, or ``SIZE_LOST_SHARE`` of them lost while the
        first frame's size is far from the references' (a misfit that does not cost answers is not said)."""
        if match.lost:
            self.lost[match.lost_why or UNSAID] += 1
        else:
            self.answered += 1
        if self.frame_size is None and frame is not None and frame.image is not None:
            self.frame_size = (int(frame.image.shape[1]), int(frame.image.shape[0]))
        if self.frames != FIRST_STRETCH or self.warned:
            return []
        lost = sum(self.lost.values())
        misfit = (self.ref_size is not None and self.frame_size is not None
                  and size_misfit(self.frame_size, self.ref_size))
        size = f"; frames are {self._size_text()}" if misfit else ""
        if lost >= LOST_SHARE * FIRST_STRETCH:
            return [self._say("lost", f"{lost} of the first {FIRST_STRETCH} frames lost: this stream hardly fits "
                                      f"the map (check that it is the map's route, camera and model{size}; the "
                                      f"lost line: " + said("{opt.min_confidence}") + ")")]
        if misfit and lost >= SIZE_LOST_SHARE * FIRST_STRETCH:
            return [self._say("size", f"{lost} of the first {FIRST_STRETCH} frames lost, and frames are "
                                      f"{self._size_text()}: frames far from the references' size match less "
                                      f"well (check that the camera and its resolution are the ones the map "
                                      f"was built from)")]
        return []

    def _say(self, key: str, text: str) -> str:
        self.warned.add(key)
        return text

    def _size_text(self) -> str:
        assert self.frame_size is not None and self.ref_size is not None
        return (f"{self.frame_size[0]}x{self.frame_size[1]} pixels, the map's references "
                f"{self.ref_size[0]}x{self.ref_size[1]}")

    def lines(self, wall_s: float, ended: str) -> list[str]:
        """The summary, a few lines: how the stream ended (``ended``), then frames, ``wall_s`` seconds of
        matching and the rate, answered, lost by reason (most first), undecodable frames skipped."""
        rate = f" ({self.frames / wall_s:.1f} frames/s)" if wall_s > 0 and self.frames else ""
        reasons = ", ".join(f"{why} {n}" for why, n in sorted(self.lost.items(), key=lambda kv: (-kv[1], kv[0])))
        lost = sum(self.lost.values())
        counts = f"{self.answered} answered, {lost} lost" + (f" ({reasons})" if lost else "")
        skipped = f", {self.skipped} undecodable skipped" if self.skipped else ""
        return [f"stream ended: {ended}",
                f"{self.frames} frame{'' if self.frames == 1 else 's'} in {wall_s:.1f} s{rate}: {counts}{skipped}"]


def reference_size(meta: dict) -> tuple[int, int] | None:
    """The map's reference images' (width, height) in pixels, from its metadata (``frame_size``; a map built
    before that was recorded: its ``model_choice``, ``camera WxH: ...``); None when it does not say."""
    size = meta.get("frame_size")
    if isinstance(size, list) and len(size) == 2 and all(isinstance(v, int) and v > 0 for v in size):
        return size[0], size[1]
    choice = meta.get("model_choice")
    if isinstance(choice, str) and choice.startswith("camera "):
        w, _, h = choice[len("camera "):].split(":", 1)[0].partition("x")
        if w.isdigit() and h.isdigit() and int(w) > 0 and int(h) > 0:
            return int(w), int(h)
    return None
