"""Every matcher by name: ``localize``, ``evaluate``, the tools and the tests read this table.

Adding a matcher is one module and one line here. Presets of one implementation (the DTW variants) are
entries with other parameters, as hloc names its configurations.
"""
from __future__ import annotations

from vpr_edge.matchers import params as P
from vpr_edge.matchers.base import Matcher
from vpr_edge.matchers.bayes import bayes_filter
from vpr_edge.matchers.dtw import dtw_match
from vpr_edge.matchers.road import stream_matcher
from vpr_edge.matchers.seqslam import SeqSLAMOnline, seqslam_match
from vpr_edge.matchers.single import BestMatch
from vpr_edge.matchers.stream_dtw import StreamingDTW
from vpr_edge.matchers.constants import TARGET_PRECISION


MATCHERS: dict[str, Matcher] = {m.name: m for m in (
    Matcher("stream", "a Bayes filter over (place, speed) and off the map: any speed 0-4 places/frame, stops, "
            "detours; its confidence is the probability the answer is right, lost below the target precision "
            "(online, default)", start=bayes_filter, definitions=P.STREAM, min_confidence=TARGET_PRECISION,
            reads_route=True, probability=True),
    Matcher("stream-rules", "trajectories over (position, speed) with contrast-normalised similarities and rules "
            "for the lost state: any speed 0-4 places/frame, lock-on anywhere; answers more where the filter is "
            "unsure, and more of them wrong (online)", start=stream_matcher, definitions=P.STREAM_RULES,
            min_confidence=1.0, reads_route=True),
    Matcher("single", "best single match per frame, no sequence information (online)", start=BestMatch),
    Matcher("stream-dtw", "decayed streaming DTW over 1 - cos (online; the first streaming matcher, kept "
            "as a baseline)", start=StreamingDTW, definitions=P.STREAM_DTW),
    Matcher("dtw", "offline DTW, fixed ends (0,0)->(Q-1,R-1), distance form", align=dtw_match, definitions=P.DTW),
    Matcher("dtw-thesis", "offline DTW, fixed ends, similarity form (the thesis's)", align=dtw_match,
            definitions=P.DTW, params=P.defaults(P.DTW, variant="similarity")),
    Matcher("dtw-open", "offline subsequence DTW, open ends, 0-4 references per frame, distance form, "
            "hubs removed (similarities z-scored per frame, each reference's mean subtracted)",
            align=dtw_match, definitions=P.DTW, params=P.defaults(P.DTW, open_ends=True, hubs=True)),
    Matcher("svm", "one linear SVM per reference place, trained at build time (build-map --svm); the place with "
            "the highest decision value (the thesis's classifier baseline, online)", start=BestMatch, scores="svm"),
    Matcher("seqslam", "SeqSLAM (Milford & Wyeth 2012), window centred on each frame (offline)",
            align=seqslam_match, definitions=P.SEQSLAM),
    Matcher("seqslam-online", "SeqSLAM over the past ds frames only (online)", start=SeqSLAMOnline,
            definitions=P.SEQSLAM),
)}


DEFAULT_MATCHER = "stream"   # what localize runs without --mode, and evaluate sets beside its baselines


def get_matcher(name: str) -> Matcher:
    """The registered matcher ``name``; ValueError listing the names if there is none."""
    try:
        return MATCHERS[name]
    except KeyError:
        raise ValueError(f"unknown matcher {name!r}; choose from {', '.join(MATCHERS)}") from None


def params_table() -> str:
    """Every registered matcher's parameters as a Markdown table (docs/matchers.md)."""
    lines = ["| matcher | parameter | default | meaning |", "|---|---|---|---|"]
    for m in MATCHERS.values():
        for key, value in m.params.items():
            lines.append(f"| `{m.name}` | `{key}` | `{value}` | {m.definitions[key].meaning} |")
    return "\n".join(lines)
