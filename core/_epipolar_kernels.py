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
    M, d, n = kin.marker_joint.shape[0], q0.shape[0], width * (1 + tries)
    # Beams (at most ``width``) and the assignments grown from them (at most ``n``): candidate
    # per marker, posture, marker places, and (squared residual, charges).
    assigned, q, places, cost = (np.full((width, M), -1, dtype=np.int64), np.empty((width, d)),
                                 np.empty((width, M, 3)), np.zeros((width, 2)))
    g_assigned, g_q, g_places, g_cost = (np.empty((n, M), dtype=np.int64), np.empty((n, d)),
                                         np.empty((n, M, 3)), np.empty((n, 2)))
    for i in range(d):
        q[0, i] = q0[i]
    _place(q, places, 0, kin)
    goal = np.empty((M, 3))
    beams = 1
    for m in order:
        grown = 0
        for b in range(beams):
            _copy_beam(g_assigned, g_q, g_places, g_cost, grown, assigned, q, places, cost, b)
            g_cost[grown, 1] += skip
            grown += 1
            for k in _allowed(m, assigned[b], places[b, m], targets, apart, doubt, from_base, low, high,
                              tries):
                _copy_beam(g_assigned, g_q, g_places, g_cost, grown, assigned, q, places, cost, b)
                g_assigned[grown, m] = k
                for j in range(M):
                    for a in range(3):
                        goal[j, a] = targets[g_assigned[grown, j], a] if g_assigned[grown, j] >= 0 else np.nan
                solved = refine(q[b], bounds, kin, views, image, np.inf, ik_steps, goal)
                for i in range(d):
                    g_q[grown, i] = solved[i]
                _place(g_q, g_places, grown, kin)
                g_cost[grown, 0] = _squared_distance(g_places[grown], goal)
                g_cost[grown, 1] += doubt[k]
                grown += 1
        total = np.empty(grown)
        for i in range(grown):
            total[i] = g_cost[i, 0] + g_cost[i, 1]
        keep = _order(total, total)
        beams = min(width, grown)
        for b in range(beams):
            _copy_beam(assigned, q, places, cost, b, g_assigned, g_q, g_places, g_cost, keep[b])
    total = np.empty(beams)
    for b in range(beams):
        total[b] = cost[b, 0] + cost[b, 1]
    return assigned[:beams], q[:beams], total


@njit(cache=True, nogil=True)
def _copy_beam(assigned, q, places, cost, i, from_assigned, from_q, from_places, from_cost, j) -> None:
    """Row ``i`` of the beam arrays takes row ``j`` of the ``from_`` ones (explicit loops:
    less code to compile than array assignments)."""
    for a in range(assigned.shape[1]):
        assigned[i, a] = from_assigned[j, a]
        for c in range(3):
            places[i, a, c] = from_places[j, a, c]
    for a in range(q.shape[1]):
        q[i, a] = from_q[j, a]
    cost[i, 0], cost[i, 1] = from_cost[j, 0], from_cost[j, 1]


@njit(cache=True, nogil=True)
def _place(q, places, i, kin) -> None:
    """``places[i]`` (M, 3): the world markers of the branch posed at ``q[i]``."""
    world = marker_positions_many(q[i : i + 1], kin)[0]
    for a in range(world.shape[0]):
        for c in range(3):
            places[i, a, c] = world[a, c]


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
    M, K = assigned.shape[0], targets.shape[0]
    index, support, near = np.empty(K, dtype=np.int64), np.empty(K), np.empty(K)
    n = 0
    for k in range(K):
        ok = low[m, M] <= from_base[k] <= high[m, M]
        for j in range(M):
            if assigned[j] >= 0:
                ok = ok and assigned[j] != k and low[m, j] <= apart[assigned[j], k] <= high[m, j]
        if ok:
            index[n], support[n] = k, doubt[k]
            near[n] = math.sqrt((targets[k, 0] - place[0]) ** 2 + (targets[k, 1] - place[1]) ** 2
                                + (targets[k, 2] - place[2]) ** 2)
            n += 1
    rank = _order(support[:n], near[:n])
    out = np.empty(min(tries, n), dtype=np.int64)
    for i in range(out.shape[0]):
        out[i] = index[rank[i]]
    return out


@njit(cache=True, nogil=True)
def _order(first, then):
    """Indices (n,) that sort by ``first`` (n,), ties by ``then``, equal pairs in their order
    (insertion sort: a few dozen entries, and far less code to compile than ``np.argsort``)."""
    out = np.arange(first.shape[0])
    for i in range(1, out.shape[0]):
        j, moving = i, out[i]
        while j > 0 and (first[moving] < first[out[j - 1]]
                         or (first[moving] == first[out[j - 1]] and then[moving] < then[out[j - 1]])):
            out[j] = out[j - 1]
            j -= 1
        out[j] = moving
    return out
