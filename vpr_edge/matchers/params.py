"""Every matcher parameter, defined once: its default and what it means. The registry builds each matcher's
presets from these tables, ``localize --list-params`` prints them, and ``docs/matchers.md`` is written from
them (``python -m vpr_edge.matchers`` prints that table). Values given on the command line
(``--param KEY=VALUE``) are read here (``read_items``) as the default's type and checked by the matcher
itself (``Matcher.parse_params``)."""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from vpr_edge.errors import Message
from vpr_edge.matchers.constants import MEMORY, OFF


@dataclass(frozen=True)
class Param:
    """A matcher parameter: its ``default`` (whose type a given value is read as) and its ``meaning``."""

    default: Any
    meaning: str


# the ``stream-rules`` matcher (``road``): trajectories and the rules of its lost state
STREAM_RULES: dict[str, Param] = {
    "vmax": Param(4.0, "fastest speed followed, in references per frame"),
    "grid": Param(2, "positions per reference (2: half-reference steps)"),
    "decay": Param(0.9, "each frame discounts a trajectory's past evidence by this factor (about 1/(1-decay) "
                        "frames remembered)"),
    "bias": Param(1.0, "what a frame's normalised similarity must exceed to extend a trajectory; higher = "
                       "more frames reported lost"),
    "turn": Param(1.0, "cost of a change of speed, per reference per frame"),
    "memory": Param(50.0, "frames in each reference's running mean (subtracted to remove look-alike hubs)"),
    "lock": Param(6.0, "trajectory score below which the frame is reported lost"),
    "evidence": Param(1.5, "the answer is reported lost unless its similarity stands at least this many "
                           "standard deviations above its frame's similarities to the route (best within 1 "
                           "reference, averaged over frames with evidence_decay; a standing frame may raise the "
                           "average, not lower it); %g = off" % OFF),
    "evidence_decay": Param(0.5, "weight of the past in that average (0: this frame alone)"),
    "hub": Param(1.0, "the answer is reported lost unless that similarity, less its place's mean over this "
                      "stream's recent moving frames (a place that looks like every frame: imagery of somewhere "
                      "else), stands at least this many standard deviations above them too (averaged the same "
                      "way); %g = off" % OFF),
    "unique": Param(0.25, "the answer is reported lost unless its uniqueness (1 - (H_rival + 1) / (H_best + 1): "
                         "how far the best trajectory leads the best one beyond rival_window) is at least this; "
                         "0 = off"),
    "confirm": Param(3, "the answer is reported lost until the best trajectory's place has held for this many "
                        "frames (each within rival_window of the frame before's, counted from the stream's first "
                        "frame or the place's last jump: back onto the map after a detour, onto a look-alike "
                        "ahead); 1 = off"),
    "stuck": Param(4, "the answer is reported lost once its place has not moved on (one reference ahead, or a "
                      "jump) while the camera moved for this many frames (as the motion cue says: frames of a standing "
                      "camera do not count; without a cue the rule is off): a place every frame resembles; "
                      "0 = off"),
    "trust": Param(0.6, "a frame that fails the evidence line alone is answered when its uniqueness (against the "
                        "answer's own drive) is at least this: an unambiguous trajectory outweighs a weak view "
                        "(the hub line still applies); 1 = off"),
    "rival_window": Param(10, "references either side of the answer that a rival trajectory must lie beyond "
                              "(the uniqueness part of the score); on a map whose references stay alike further "
                              "along the route, as far as they do (likeness.reach, measured on the map)"),
    "window": Param(100, "local search: references either side of a firm lock read per frame, on routes of "
                         "more than 4x this (0 = every reference every frame)"),
    "probe": Param(512, "local search: fixed random references that estimate a frame's similarity mean and "
                        "spread"),
    "check": Param(100, "local search: every this many firmly locked frames, search the whole route ..."),
    "span": Param(5, "... for this many frames"),
    "hold": Param(2.0, "a lock is firm (local search allowed) at this many times the lock score"),
    "seek": Param(8, "index search (maps with an index): on a whole-route frame, references either side of each "
                     "of the index's candidates searched ..."),
    "peaks": Param(8, "... beside the neighbourhoods (window/4 references either side) of this many best "
                      "hypotheses held; the index is asked with ..."),
    "seek_frames": Param(4, "... the mean of the encodings of the last this many frames (this one included): "
                            "their noise averages out, the places they show are alike"),
    "stop_gain": Param(0.3, "without a motion cue: at speed 0, the share of a frame's positive evidence counted "
                            "(standing still is not new evidence)"),
    "stop_decay": Param(0.95, "without a motion cue: at speed 0, the decay of the trajectory score (a lock holds "
                              "through a stop)"),
    "still": Param(0.5, "motion cue: a frame that differs from the last moving frame by at most (1 - still) of "
                        "this stream's typical moving step (cue >= still) shows a standing camera and leaves the "
                        "state as it was (the answer stays), unless the map's own drive stood there too; below it "
                        "the camera moves (speed 0 gains nothing, decays as the others); 0 = no cue: stop_gain and "
                        "stop_decay for every frame"),
    "still_memory": Param(MEMORY, "motion cue: moving frames whose median step (1 - cosine of encodings) is the "
                                  "stream's typical moving step"),
}
# the default ``stream`` matcher (``bayes``): the motion model, the likelihood, the confidence and the motion
# cue. Chosen on nordland-dev, reported on Corridor (docs/decisions.md, "The stream filter's parameters")
STREAM: dict[str, Param] = {
    "vmax": Param(4, "fastest speed followed, in places per frame (speeds 0..vmax)"),
    "speed_step": Param(0.5, "the speeds followed above standing and half a place a frame run from one place per "
                             "frame to vmax in steps of this (1, 0.5 or 0.25; 0.5: 1, 1.5, 2, ..)"),
    "speed_change": Param(0.03, "probability a frame's speed is the next one up (and the same, the next one down)"),
    "leave": Param(0.01, "probability a frame leaves the map (a detour, a road the map does not hold)"),
    "enter": Param(0.05, "probability a frame off the map comes back onto it, at any place"),
    "jump": Param(0.001, "probability a frame's place jumps anywhere on the map (a re-localisation)"),
    "temper": Param(0.45, "the share of a frame's evidence counted: neighbouring frames and places look alike, "
                         "so a frame is worth less than an independent observation (1: all of it)"),
    "hub_memory": Param(50.0, "frames in each place's running mean similarity, subtracted so that a place "
                              "that looks like every frame is no evidence (0: off)"),
    "scale_memory": Param(100.0, "frames in the running estimate of how far the true place stands out of a "
                                 "frame's similarities (the likelihood's scale)"),
    "tolerance": Param(2, "the confidence is the probability that the true place lies within this many places "
                          "of the answer"),
    "rival_window": Param(10, "places either side of the answer beyond which doubt counts as another stretch "
                              "of the route (lost_why 'ambiguous'); at least the map's likeness reach"),
    "still": Param(0.5, "motion cue: a frame whose cue is at least this (it differs from the last moving frame "
                        "by at most half a typical moving step) may show its view again: it counts only the chance "
                        "that the camera moves all the same of its evidence (every cue weighs speed 0 against "
                        "moving, CUE_STANDING); 0 = no cue"),
    "still_memory": Param(MEMORY, "motion cue: moving frames whose median step (1 - cosine of encodings) is the "
                                  "stream's typical moving step"),
    "window": STREAM_RULES["window"], "probe": STREAM_RULES["probe"], "check": STREAM_RULES["check"],
    "span": STREAM_RULES["span"],
    "hold": Param(0.9, "local search: an answer is firm (the next frame may read its window only) at this "
                       "confidence"),
    "seek": STREAM_RULES["seek"], "peaks": STREAM_RULES["peaks"], "seek_frames": STREAM_RULES["seek_frames"],
}
STREAM_DTW: dict[str, Param] = {
    "decay": Param(0.9, "each frame discounts the accumulated path cost by this factor"),
}
DTW: dict[str, Param] = {
    "variant": Param("distance", "distance: minimise summed 1 - cosine; similarity: maximise summed cosine "
                                 "(the thesis)"),
    "open_ends": Param(False, "let the path start and end anywhere, 0..max_step references per frame"),
    "max_step": Param(4, "with open_ends: most references the path advances per frame"),
    "rival_window": Param(5, "the score is the margin over the best path avoiding this many references "
                             "either side of the answer"),
    "hubs": Param(False, "z-score each frame's similarities and subtract each reference's mean first"),
}
SEQSLAM: dict[str, Param] = {
    "ds": Param(10, "trajectory length in frames (SeqSLAM's ds)"),
    "vmin": Param(0.5, "slowest trajectory speed, references per frame"),
    "vmax": Param(3.0, "fastest trajectory speed, references per frame"),
    "r_window": Param(10, "local contrast enhancement window, references"),
    "match_window": Param(10, "the ratio test's rival lies more than match_window/2 references away"),
}


def defaults(table: dict[str, Param], **overrides: Any) -> dict[str, Any]:
    """The default values of ``table``, with some presets changed (an unknown name is a KeyError)."""
    for k in overrides:
        table[k]   # noqa: B018 - a preset must name a defined parameter
    return {k: p.default for k, p in table.items()} | overrides


def read_items(items: Sequence[str], current: dict[str, Any], owner: str) -> dict[str, Any]:
    """``["key=value", ...]`` (the CLI's ``--param``) -> overrides of the parameters ``current`` (name ->
    value) of the matcher ``owner``, each value read as its current value's type (bool: true/false/1/0).
    ValueError naming the item for an unknown key or a value that does not read. (Whether the matcher takes
    the value is ``Matcher.parse_params``'s check.)"""
    out: dict[str, Any] = {}
    for item in items:
        _, sep, text = item.partition("=")
        key = param_key(item)
        if not sep or key not in current:
            raise ValueError(Message("{opt.params} {item!r}: {owner} takes KEY=VALUE with KEY one of {keys}",
                                     item=item, owner=owner, keys=", ".join(current) or "(none)"))
        out[key] = _read_value(text.strip(), current[key], item)
    return out


def param_key(item: str) -> str:
    """The parameter name of a ``--param`` item ``"key=value"`` (dashes read as underscores)."""
    return item.partition("=")[0].strip().replace("-", "_")


def _read_value(text: str, default: Any, item: str) -> Any:
    """``text`` read as the type of ``default`` (bool, int, float or str); ValueError naming ``item``."""
    try:
        if isinstance(default, bool):
            if text.lower() not in ("true", "false", "1", "0"):
                raise ValueError
            return text.lower() in ("true", "1")
        if isinstance(default, int):
            return int(text)
        if isinstance(default, float):
            value = float(text)
            if not math.isfinite(value):
                raise ValueError
            return value
        return text
    except ValueError:
        kind = {"bool": "a bool (true/false)", "int": "an int", "float": "a number"}.get(type(default).__name__, "text")
        raise ValueError(Message("{opt.params} {item!r}: {text!r} is not {kind}", item=item, text=text,
                                 kind=kind)) from None
