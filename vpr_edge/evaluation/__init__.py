"""Evaluation, apart from the matchers: ground truth (``truth``), metrics over matcher results (``metrics``),
one matcher scored (``scoring``), the similarity sources and the whole ``evaluate`` (``sources``, ``run``) and
reports (``report``; its figures drawn in ``figures``). The test streams derived from aligned datasets, and the
experiments run on them, are the lab's (``vpr_edge_bench``, beside this package in a checkout, not in the wheel)."""
from vpr_edge.evaluation.run import Evaluation, Source, evaluate
from vpr_edge.evaluation.scoring import ModeReport, evaluate_mode, score_result
from vpr_edge.evaluation.truth import Truth

__all__ = ["Evaluation", "ModeReport", "Source", "Truth", "evaluate", "evaluate_mode", "score_result"]
