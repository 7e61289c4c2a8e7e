"""Matchers: pure functions of a similarity matrix (or a stream of its rows): one contract (``base``), one
module each, one registry (``registry.MATCHERS``), every parameter defined once (``params``)."""
from vpr_edge.matchers.base import (LOST_WHY, Matcher, OnlineMatcher, Result, WholeRoute, check_lost_line,
                                    check_target_precision, is_lost, lost_why, run_online, run_rows, step, top_k)
from vpr_edge.matchers.motion import MotionCue, cue_at, route_stands, stands, stillness
from vpr_edge.matchers.params import Param, param_key
from vpr_edge.matchers.registry import DEFAULT_MATCHER, MATCHERS, get_matcher

__all__ = ["DEFAULT_MATCHER", "LOST_WHY", "MATCHERS", "Matcher", "MotionCue", "OnlineMatcher", "Param", "Result",
           "WholeRoute", "check_lost_line", "check_target_precision", "cue_at", "get_matcher", "is_lost", "lost_why",
           "param_key", "route_stands", "run_online", "run_rows", "stands", "step", "stillness", "top_k"]
