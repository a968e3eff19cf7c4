"""Compiled beam search of ``core.epipolar_start``: a branch's markers assigned to triangulated
candidates, one marker at a time, each partial assignment solved by inverse kinematics
(``core._kernels.refine`` in target mode). Compiled whole: the search runs some 75 inverse
kinematics per branch, and in Python each cost as much again in interpreter work.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from core._kernels import marker_positions_many, refine


@njit(cache=True, nogil=True)
def beam_search(order, q0, kin, bounds, views, image, targets, from_base, apart, doubt, low, high,
                skip, width, tries, ik_steps):
    """The final partial assignments of the beam search and their postures.

    Each marker of ``order`` (M,), in turn, is left out (charged ``skip``) or given each of
    at most ``tries`` free candidates :func:`_allowed` lets it take, in every beam; the
    branch is solved onto each new assignment from its beam's posture (``ik_steps``
    Levenberg-Marquardt steps within ``bounds``), and the ``width`` assignments of least
    cost (squared residual plus charges, model units²; ties in the order made) go on.

    Parameters: ``kin`` the branch posed at its base; ``q0`` (d,) its start; ``targets``
    (K, 3) the candidates within reach, ``from_base`` (K,) and ``apart`` (K, K) their
    distances from the base origin and from each other, ``doubt`` (K,) the charge of
    assigning each; ``low``, ``high`` (M + 1, M + 1) the distance intervals between the
    branch's markers and its base origin (last). ``views``, ``image``: refine's, not read.

    Returns (assigned (B, M) int64, candidate per marker or -1; postures (B, d); costs (B,)).
    """
    M, d = kin.marker_joint.shape[0], q0.shape[0]
    assigned = np.full((1, M), -1, dtype=np.int64)
    q = q0.copy().reshape(1, d)
    places = marker_positions_many(q, kin)
    residual, charges = np.zeros(1), np.zeros(1)
    goal = np.empty((M, 3))
    for m in order:
        n = assigned.shape[0] * (1 + tries)
        g_assigned, g_q, g_places = np.empty((n, M), dtype=np.int64), np.empty((n, d)), np.empty((n, M, 3))
        g_residual, g_charges = np.empty(n), np.empty(n)
        grown = 0
        for b in range(assigned.shape[0]):
            g_assigned[grown], g_q[grown], g_places[grown] = assigned[b], q[b], places[b]
            g_residual[grown], g_charges[grown] = residual[b], charges[b] + skip
            grown += 1
            for k in _allowed(m, assigned[b], places[b, m], targets, apart, doubt, from_base, low, high,
                              tries):
                g_assigned[grown] = assigned[b]
                g_assigned[grown, m] = k
                goal[:] = np.nan
                for j in range(M):
                    if g_assigned[grown, j] >= 0:
                        goal[j] = targets[g_assigned[grown, j]]
                g_q[grown] = refine(q[b], bounds, kin, views, image, np.inf, ik_steps, goal)
                g_places[grown] = marker_positions_many(g_q[grown].reshape(1, d), kin)[0]
                g_residual[grown] = _squared_distance(g_places[grown], goal)
                g_charges[grown] = charges[b] + doubt[k]
                grown += 1
        keep = np.argsort(g_residual[:grown] + g_charges[:grown], kind="mergesort")[:width]
        assigned, q, places = g_assigned[keep], g_q[keep], g_places[keep]
        residual, charges = g_residual[keep], g_charges[keep]
    return assigned, q, residual + charges


@njit(cache=True, inline="always")
def _squared_distance(places, goal) -> float:
    """Sum of squared distances (model units²) of ``places`` (M, 3) to ``goal`` (M, 3), the
    markers without a goal (NaN) left out."""
    total = 0.0
    for j in range(places.shape[0]):
        if not math.isnan(goal[j, 0]):
            for a in range(3):
                total += (places[j, a] - goal[j, a]) ** 2
    return total


@njit(cache=True, nogil=True)
def _allowed(m, assigned, place, targets, apart, doubt, from_base, low, high, tries):
    """Candidates (indices) marker ``m`` may take beside ``assigned`` (M,): free, at distances
    from the base and from the assigned candidates within the sampled intervals; the
    ``tries`` best supported (least ``doubt``), nearest the marker's ``place`` (3,) first."""
    M = assigned.shape[0]
    ok = (from_base >= low[m, M]) & (from_base <= high[m, M])
    for j in range(M):
        if assigned[j] >= 0:
            ok[assigned[j]] = False
            ok &= (apart[assigned[j]] >= low[m, j]) & (apart[assigned[j]] <= high[m, j])
    index = np.flatnonzero(ok)
    near = np.empty(index.shape[0])
    for i in range(index.shape[0]):
        k = index[i]
        near[i] = math.sqrt((targets[k, 0] - place[0]) ** 2 + (targets[k, 1] - place[1]) ** 2
                            + (targets[k, 2] - place[2]) ** 2)
    by_place = np.argsort(near, kind="mergesort")
    rank = by_place[np.argsort(doubt[index[by_place]], kind="mergesort")]
    return index[rank[:tries]]
