"""Fitting runs its linear algebra on one thread per process.

The fit's matrices are small (a 42-DOF model's Jacobian is a few hundred rows by 42
columns; ``core.undetermined`` inverts and decomposes such matrices once per image), and a
BLAS library that spreads each of them over every core spends more CPU time starting and
waiting for its threads than computing. ``mocap fit`` and the service already use every
core through processes, one chunk or one image each, so threads inside a process only
compete with the other processes. One thread also makes a fit's floating-point sums, and
so its postures, the same on a 2-core laptop and a 64-core server.

:func:`one_blas_thread` wraps the entry points that fit images (``core.sequence.fit_chunk``,
``core.fit.reanalyse_image``); entering it costs about 0.2 ms, once per chunk or attempt.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import ParamSpec, TypeVar

from threadpoolctl import threadpool_limits

__all__ = ["one_blas_thread"]

P = ParamSpec("P")
R = TypeVar("R")


def one_blas_thread(fn: Callable[P, R]) -> Callable[P, R]:
    """``fn`` run with the BLAS and LAPACK libraries that NumPy loaded limited to one
    thread, their previous limits restored on return."""

    @functools.wraps(fn)
    def limited(*args: P.args, **kwargs: P.kwargs) -> R:
        with threadpool_limits(limits=1, user_api="blas"):
            return fn(*args, **kwargs)

    return limited
