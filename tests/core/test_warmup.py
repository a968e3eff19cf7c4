"""core.warmup: the kernels a fit runs are compiled (or loaded) by one call, needing no file."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from core import _detect_kernels, _histogram_kernels, _kernels
from core.warmup import compile_kernels

ROOT = Path(__file__).resolve().parents[2]

# A new process runs the warm-up and counts, over every kernel, the signatures numba loaded
# from its on-disk cache and those it had to compile.
COUNT_LOADS = """
from numba.core.registry import CPUDispatcher
from core import _detect_kernels, _histogram_kernels, _kernels
from core.warmup import compile_kernels
compile_kernels()
kernels = [k for module in (_kernels, _detect_kernels, _histogram_kernels) for k in vars(module).values()
           if isinstance(k, CPUDispatcher)]
print(sum(sum(k.stats.cache_hits.values()) for k in kernels),
      sum(sum(k.stats.cache_misses.values()) for k in kernels))
"""


def test_one_call_compiles_the_kernels_a_chain_and_a_tree_fit_run():
    assert compile_kernels() > 0.0
    for kernel in (_kernels.fit_attempt, _kernels.refine, _kernels.posture_error,
                   _kernels.forward_kinematics, _kernels.flip_alternatives, _detect_kernels.detect_regions,
                   _histogram_kernels.eq4_update):
        assert kernel.signatures, kernel.__name__


def test_a_second_process_loads_every_kernel_from_the_cache_compiling_none():
    compile_kernels()  # fills the cache, if this process compiled
    env = os.environ | {"PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    result = subprocess.run([sys.executable, "-c", COUNT_LOADS], env=env, cwd=ROOT, capture_output=True,
                            text=True, check=True, timeout=600)
    loaded, compiled = (int(n) for n in result.stdout.split()[-2:])
    assert loaded >= 10, result.stdout
    assert compiled == 0, result.stdout


def test_a_kernel_whose_cache_numba_keeps_elsewhere_counts_as_not_cached():
    """``_cached`` reads numba's private cache index; where a numba release moved it, the
    warm-up must read "not cached" (one more compiling process), not fail."""
    from types import SimpleNamespace

    from core.warmup import _cached

    assert _cached(SimpleNamespace(_cache=object(), stats=None)) is False


def test_the_warm_up_compiles_at_its_own_level_unless_numba_opt_is_set(monkeypatch):
    """``core.warmup.OPT_LEVEL`` inside the warm-up, numba's own level restored after it; a level
    the user set in ``NUMBA_OPT`` stands."""
    from numba.core import config

    from core.warmup import OPT_LEVEL, _optimisation_level

    before = config.OPT
    monkeypatch.delenv("NUMBA_OPT", raising=False)
    with _optimisation_level():
        assert config.OPT == OPT_LEVEL != 0  # at 0 numba cannot cache the kernels
    assert config.OPT is before
    monkeypatch.setenv("NUMBA_OPT", "2")
    with _optimisation_level():
        assert config.OPT is before
