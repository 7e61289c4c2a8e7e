"""The optional extras an output needs, checked before the work without importing them (``localize`` without
``--view``, ``--rerun`` or an ``.mcap`` output never loads Rerun or mcap)."""
from __future__ import annotations

import importlib.util

from vpr_edge.errors import InputError, Message

# extra -> (the module it provides, the distribution pip installs)
EXTRAS = {"view": ("rerun", "rerun-sdk"), "mcap": ("mcap", "mcap")}


def require(extra: str, option: "str | Message") -> None:
    """InputError (one line naming ``option`` and the pip command) unless the extra's module is installed."""
    module, dist = EXTRAS[extra]
    if importlib.util.find_spec(module) is None:
        raise InputError("{option} needs {dist}: pip install 'vpr-edge[{extra}]'", option=option, dist=dist, extra=extra)
