"""core.warmup: the kernels a fit runs are compiled (or loaded) by one call, needing no file."""

from __future__ import annotations

from core import _kernels
from core.warmup import compile_kernels


def test_one_call_compiles_the_kernels_a_chain_and_a_tree_fit_run():
    assert compile_kernels() > 0.0
    for kernel in (_kernels.fit_attempt, _kernels.refine, _kernels.posture_error,
                   _kernels.forward_kinematics, _kernels.flip_alternatives, _kernels.detect_regions):
        assert kernel.signatures, kernel.__name__
