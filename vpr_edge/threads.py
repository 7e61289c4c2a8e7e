"""One thread budget for the two pools a frame passes through: onnxruntime's and NumPy's BLAS.

Left at their defaults on a 2-core board, the two pools fight (docs/decisions.md, "Tried and not taken"). Stages
run one after the other, so each pool may use the whole budget; what matters is that neither grows past it
and that onnxruntime's idle workers do not spin (``features.cnn.FeatureExtractor`` turns spinning off).
"""
from __future__ import annotations

import os


def cores() -> int:
    """CPU cores this process may run on (its affinity mask, not the machine's count)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


MAX_PER_CORE = 4   # threads asked for beyond this many per core are refused (a typo, not a plan)


def use_threads(threads: int) -> int:
    """Limit NumPy's BLAS pool, process-wide, to ``threads`` (0 = one per core) and return the count to
    give onnxruntime. Uses threadpoolctl, which finds the BLAS library NumPy actually loaded (OpenBLAS,
    MKL, BLIS) and sets its pool at run time, where environment variables act only before NumPy loads."""
    from vpr_edge.errors import InputError

    if threads > MAX_PER_CORE * cores():
        raise InputError("{opt.threads} {threads}: more than {most} per core of the {cores} this process may use "
                         "only slows both pools down (0 = one per core)", threads=threads, most=MAX_PER_CORE,
                         cores=cores())
    n = threads if threads > 0 else cores()
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # a runtime installed without it still runs; BLAS keeps its own default
        from vpr_edge.errors import warn

        warn("threadpoolctl is not installed: NumPy's BLAS threads are not limited (pip install threadpoolctl)")
        return n
    threadpool_limits(limits=n, user_api="blas")
    return n
