"""Matchers: one contract (``base``), one module each, one registry (``registry.MATCHERS``)."""
from vpr_edge.matchers.base import Matcher, OnlineMatcher, Result, param_key, run_online, run_rows, step, top_k
from vpr_edge.matchers.registry import MATCHERS, get_matcher

__all__ = ["MATCHERS", "Matcher", "OnlineMatcher", "Result", "get_matcher", "param_key", "run_online", "run_rows",
           "step", "top_k"]
