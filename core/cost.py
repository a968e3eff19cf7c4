"""What one attempt on one image costs, estimated from sizes before anything runs.

A fit's work grows with the model faster than linearly: one evaluation of the objective
(Eq. 5) projects every marker into every view and matches it to the view's detections (V·M·N),
and one Levenberg–Marquardt step of the refinement takes the Jacobian (the markers' world
Jacobian through each projection, V·M·D) and builds and solves the D×D normal equations
(V·M·D² + D³). A model of 1000 joints is within the file limits but one image of it runs for
hours; a worker busy that long is a worker lost to every other job.
:func:`estimate_fit_cost` bounds one attempt from above (every restart runs, each SA run all
its iterations and polish rounds, then the final refinements and the depth-flip search; a
hard image whose error keeps falling 1 % a round does all that), and :func:`check_fit_cost`
refuses what no worker could finish, naming the numbers: ``mocap fit`` and the service call
it before a job starts. The unit times are measured (``bench/cost.py``,
docs/RELIABILITY.md); on another machine they are off by a constant factor, not in how they
grow.
"""

from __future__ import annotations

from dataclasses import dataclass

from core import _kernels
from core.ambiguity import MAX_FLIP_REFINES, flip_masks
from core.fit import FitParams
from core.model import KinematicModel
from core.rig import Rig
from core.undetermined import PROFILE_STEPS, WITNESS_DOUBLINGS

__all__ = ["MAX_ATTEMPT_SECONDS", "MAX_WORKSPACE_BYTES", "FitCost", "FitCostError", "check_fit_cost",
           "estimate_fit_cost"]

# Longest estimated attempt on one image that is accepted: the service's default time
# limit of a chunk task (MOCAP_TASK_SOFT_TIME_LIMIT_S), which must hold at least one image.
MAX_ATTEMPT_SECONDS = 1800.0
# Largest scratch memory of one refinement (its Jacobian and D×D matrices) accepted.
MAX_WORKSPACE_BYTES = 2**30

# Unit times, seconds, measured with bench/cost.py (2-core EPYC VM; _NORMAL_S 2026-11-29, the
# others 2026-11-23): an evaluation costs _EVALUATION_S, _JOINT_S per joint and DOF,
# _MARKER_S per projected marker and _MATCH_S per marker-detection pair; a LM step also
# _NORMAL_S per Jacobian product term (V·M·2·D², each marker's DOFs taken as all D: a chain's
# are a third of that on average) and _SOLVE_S per D³ of each damped solve.
_EVALUATION_S = 1e-6
_JOINT_S = 15e-9
_MARKER_S = 10e-9
_MATCH_S = 0.7e-9
_NORMAL_S = 0.2e-9
_SOLVE_S = 0.2e-9
# LM trials (damped solves) per step, taken as 3: one when the first solve is accepted, more
# while the damping grows.
_LM_TRIALS = 3
# LM steps of the refinements ``core._kernels`` runs: each run's final refinement and its
# refit without lost markers (50 each); a depth flip's inverse kinematics and polish (30 + 50).
_FINAL_STEPS = 100
_FLIP_STEPS = 80
_POLISHES_PER_ROUND = 3  # the best, the current and the best drawn posture


class FitCostError(ValueError):
    """A job whose fit is estimated to cost more than a worker can give; the message says why."""


@dataclass(frozen=True)
class FitCost:
    """Upper bounds of a job's work, seconds of one core (and bytes).

    evaluation_s : one evaluation of the objective (Eq. 5 with fusion).
    lm_step_s : one Levenberg–Marquardt step of the refinement.
    image_s : one attempt on one image (each restart, each SA run with every iteration and
        polish round, the final refinements, the depth-flip search).
    job_s : every image, every attempt (``images · max_attempts · image_s``).
    workspace_bytes : scratch memory of one refinement.
    """

    evaluation_s: float
    lm_step_s: float
    image_s: float
    job_s: float
    workspace_bytes: int


def estimate_fit_cost(model: KinematicModel, rig: Rig, params: FitParams, *, images: int) -> FitCost:
    """Bound the work of fitting ``images`` images of ``model`` seen by ``rig`` with ``params``.

    Detections per view are taken as one per marker (ghosts and occlusions roughly cancel).
    """
    J, D, M, V = len(model.joints), len(model.dofs), len(model.markers), len(rig.views)
    evaluation = _EVALUATION_S + _JOINT_S * (J + D) + _MARKER_S * V * M + _MATCH_S * V * M * M
    # The Jacobian, at the posture the last evaluation left: every marker's world Jacobian
    # (M·D), each projection's derivative (about two projections' work), their chain
    # (V·M·2·3·D) and the merges (V·M·M pairs).
    jacobian = (_JOINT_S * M * D + 2 * _MARKER_S * V * M + _MATCH_S * V * M * M
                + _NORMAL_S * V * M * 2 * 3 * D)
    lm_step = (jacobian + _LM_TRIALS * evaluation + _NORMAL_S * V * M * 2 * D * D
               + _SOLVE_S * _LM_TRIALS * D**3)
    a = params.anneal
    rounds = a.n_end // a.polish_every if a.polish_every else 0
    run = (a.n_end * evaluation
           + rounds * (_POLISHES_PER_ROUND * _kernels._POLISH_STEPS * lm_step + a.draws * evaluation))
    if params.refine:
        run += _FINAL_STEPS * lm_step
    image = (1 + params.restarts) * run
    if params.alternative_tolerance_px > 0:
        flip_joints = len({d.joint for d in model.dofs if d.rotational})
        screens = V * len(flip_masks(flip_joints))
        image += screens * evaluation + min(screens, MAX_FLIP_REFINES) * _FLIP_STEPS * lm_step
        # An undetermined DOF's witness: a Jacobian, then at most every step of every
        # rotational DOF both ways, each two evaluations and a refinement with the DOF held.
        steps = 2 * sum(d.rotational for d in model.dofs) * (WITNESS_DOUBLINGS + 1)
        image += ((D + 1) * evaluation + _SOLVE_S * D**3
                  + steps * (2 * evaluation + PROFILE_STEPS * lm_step))
    # 8-byte words: Jacobian and two residual arrays, the markers' world and per-view
    # Jacobians and the projections' derivatives, two assignments (raw projections,
    # detection, validity, view levels: _kernels.Assignment), normal equations and factors.
    workspace = 8 * (V * M * 2 * (D + 2) + 5 * M * D + 6 * V * M + 2 * (4 * V * M + V) + 3 * D * D + D)
    return FitCost(evaluation, lm_step, image, images * params.max_attempts * image, workspace)


def check_fit_cost(cost: FitCost, *, max_attempt_s: float = MAX_ATTEMPT_SECONDS,
                   time_limit_name: str = "MAX_ATTEMPT_SECONDS",
                   max_workspace_bytes: int = MAX_WORKSPACE_BYTES) -> None:
    """Raise :class:`FitCostError` if one image's attempt or one refinement's memory is beyond
    the limits; the message gives the estimate, the limit (``time_limit_name`` names the
    setting of ``max_attempt_s``) and what makes it large."""
    if cost.image_s > max_attempt_s:
        raise FitCostError(
            f"one attempt on one image is estimated to take up to {_duration(cost.image_s)} "
            f"(one refinement step {_duration(cost.lm_step_s)}); the limit is "
            f"{_duration(max_attempt_s)} ({time_limit_name}): use a model with fewer joints, "
            "markers or DOFs, fewer views or fewer iterations"
        )
    if cost.workspace_bytes > max_workspace_bytes:
        raise FitCostError(
            f"refining a posture would need {cost.workspace_bytes / 2**20:.0f} MiB of memory "
            f"(views × markers × DOFs); the limit is {max_workspace_bytes / 2**20:.0f} MiB "
            "(MAX_WORKSPACE_BYTES): use "
            "fewer views, markers or DOFs"
        )


def _duration(seconds: float) -> str:
    """A duration a person reads at a glance.

    >>> _duration(0.0042), _duration(0.521), _duration(95.0), _duration(1800.0), _duration(3e6)
    ('4.2 ms', '521 ms', '95 s', '30 min', '35 days')
    """
    if seconds < 1:
        return f"{seconds * 1e3:.3g} ms" if seconds >= 1e-3 else f"{seconds * 1e6:.3g} µs"
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    if seconds < 86400 * 2:
        return f"{seconds / 3600:.1f} h"
    return f"{seconds / 86400:.0f} days"
