"""The outputs of ``localize`` beside its log, for a person: the MCAP record (``-o FILE.mcap``, the mcap extra)
and the Rerun view and recording (``--view``, ``--rerun FILE.rrd``, the view extra). Their extras are checked
before the work (``check_live``) and imported only when asked for (``live_sinks``)."""
from __future__ import annotations

import os
from pathlib import Path

from vpr_edge.api import Localizer
from vpr_edge.errors import InputError, Message
from vpr_edge.outputs.sink import ResultSink
from vpr_edge.outputs.extras import require

MCAP_SUFFIX = ".mcap"


def is_mcap(out: Path | None) -> bool:
    """Whether ``--out`` names an MCAP record rather than a log."""
    return out is not None and out.suffix.lower() == MCAP_SUFFIX


def check_live(out: Path | None, fmt: str | None, view: bool, record: Path | None) -> None:
    """VprError (one line) before the work: an extra missing for what was asked, or ``--format`` given with an
    MCAP ``--out``."""
    if is_mcap(out):
        if fmt:
            raise InputError("{out}: {opt.format} {fmt} contradicts the file's {suffix} suffix (an MCAP record)",
                             out=out, fmt=fmt, suffix=out.suffix)
        require("mcap", "-o FILE.mcap")
    if view or record is not None:
        require("view", Message("{opt.view}") if view else Message("{opt.rerun}"))


def live_sinks(localizer: Localizer, map_path: str | os.PathLike[str], stream: str, out: Path | None,
               view: bool, record: Path | None) -> list[ResultSink]:
    """The sinks asked for beside the log: the Rerun view / recording (a Viewer started here, before any file
    is made) and the MCAP record at ``out`` when it is one; none otherwise."""
    sinks: list[ResultSink] = []
    name = Path(stream.rstrip("/\\")).name or stream
    if view or record is not None:
        from vpr_edge.outputs.view import RerunSink

        sinks.append(RerunSink(localizer.map, map_path, view=view, record=record, stream=name,
                               lost_line=localizer.threshold))
    if is_mcap(out):
        from vpr_edge.outputs.mcap_record import McapSink

        assert out is not None
        sinks.append(McapSink(out, localizer.map, {"map": Path(map_path).name, "stream": name,
                                                   "mode": localizer.matcher.name}))
    return sinks
