"""Compiled kernels: forward kinematics, projection, Eq. 5, Simulated Annealing, refinement.

What is in this file, and why together: numba caches each kernel (``cache=True``) per
function, keyed by this file's time stamp alone, with the code of every kernel it calls and
of every ``inline='always'`` helper compiled into it. A callee in another file could change
and leave its callers' cached code stale; so the kernels a fit calls, and all they call,
live here, and a change to any of them invalidates them all (``core.warmup`` tests one
entry, :func:`fit_attempt`'s, for the whole file). Kernels no fitting kernel calls live
beside their modules: detection and the field centroids in ``core._detect_kernels``, Eq. 4
in ``core._histogram_kernels``.

The interface is named: a fitting kernel takes the model (``core.model.KinematicArrays``),
the views (``core.rig.RigArrays``), the image (:class:`Image`), the DOF ranges
(:class:`Bounds`) and SA's settings (:class:`SAParams`) as named tuples, built in Python
(numba passes them by value) and read by field, never by position.

Everything here trusts its input: the public functions in ``model``, ``rig``,
``error``, ``anneal`` and ``refine`` validate once and call these on contiguous
float64 / int64 arrays. Angles inside the kernels are degrees unless a name says
``rad``. Views are stored as 3×4 matrices (an affine view has the third row
``[0, 0, 0, 1]``); pinhole views carry ``[R | t]`` there plus ``K`` and OpenCV's
8 distortion coefficients.

Written for the SA inner loop, which evaluates Eq. 5 some 10^5 times a second:

- joint frames live in one flat array (12 numbers a joint: rotation, origin)
  and the sines and cosines of every DOF are computed first, independently;
- data-dependent choices are selects, not branches: the quadrant of a sine,
  the nearest detection, which markers fuse. A mispredicted branch costs more
  than the arithmetic it guards (docs/ENGINE_NOTES.md);
- helpers that take arrays are inlined by numba (``inline='always'``), so the
  loop is one function and arrays are not reference-counted at every call; numba
  types an inlined helper again at every call site, so helpers of scalars alone
  (LLVM inlines them) and those called once per refinement step or outside SA's
  proposal loop are plain calls, compiled once; but a plain call's library carries the
  code of all it calls, which numba optimises again in it: a thin wrapper of big kernels
  outside SA's loop (:func:`_evaluate`) is inlined;
- no slice assignment of arrays (``a[:] = b``): numba compiles its shape-mismatch message
  (string formatting) in every process, uncached; :func:`_copy` loops;
- random numbers come from an inlined xoshiro256** generator seeded from the
  caller's ``numpy.random.Generator`` (~1 ns a draw instead of ~7 ns).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

DEG = math.pi / 180.0
AFFINE, PINHOLE, MATRIX = 0, 1, 2
BEHIND_CAMERA = 1.0e9  # pixel coordinate given to points behind a pinhole camera
FRAME = 12  # numbers per joint frame: rotation (row-major 3×3), then origin (3)
# For Python callers. Inside a kernel a global array is a read-only constant, another type: a
# kernel passing one to another kernel would compile that one a second time (and everything
# it calls), so kernels pass arrays of their own (:func:`_no_targets`, :func:`_no_unseen`,
# ``Image.unseen`` as Python gave it). A literal int is a type of its own too: kernels pass step counts as
# ``np.int64``.
NO_TARGETS = np.zeros((0, 3))  # refine in image mode
NO_UNSEEN = np.zeros((0, 0), dtype=np.bool_)  # every marker may be seen
# fusion_px in marker diameters (core.error.fusion_distance): reading every view apart as well
# makes a generous distance safe, and it must cover what the detector merges (up to ~1.3
# diameters; smaller distances read merged pairs apart: docs/ENGINE_NOTES.md, "Fusion distance").
FUSION_DIAMETERS = 2.0
# refine tightens its Huber radius to MIN_RADIUS_PX (px; nearly Eq. 5's own loss, the sum of
# lengths) where the residuals' median length is under TIGHTEN_BELOW of the radius.
TIGHTEN_BELOW = 0.5
MIN_RADIUS_PX = 0.1


# ---- records passed to the kernels -----------------------------------------------------------
# numba passes a named tuple by value, typed by its fields' types: build them in Python with the
# field types given (float() / int() / bool(), C-contiguous arrays), so one signature serves all.
# The model travels as core.model.KinematicArrays, the views as :class:`RigArrays` (built by
# core.rig.Rig.arrays).


class Image(NamedTuple):
    """One image's detections and how the objective (:func:`blob_error`) charges them.

    det : (N, 3) float64, detections of all views (u, v px, merged flag), view v in
        ``det[start[v]:start[v + 1]]`` (``core.error.Detections.kernel_points``); or (N, 4),
        the fourth column 1.0 where another part of the model explains the detection (a
        part's objective, ``core.warm_start``): :func:`_unexplained` never charges it.
    start : (V + 1,) int64.  offset : (V, 2) float64, pixels added to each view's projections.
    penalty : float, px a marker of a view without detections costs (and an unseen one).
    fuse_px : float, markers projecting closer are one blob; 0: plain Eq. 5.
    lost_px : float, > 0 lets every view lose its worst marker, charged this instead.
    unseen : (V, M) bool, markers charged ``penalty`` whatever they project on; (0, 0): none.
        A marker outside its view's region is charged so too (:func:`charged_unseen`).
    """

    det: np.ndarray
    start: np.ndarray
    offset: np.ndarray
    penalty: float
    fuse_px: float
    lost_px: float
    unseen: np.ndarray

    @classmethod
    def of(cls, det: np.ndarray, start: np.ndarray, offset: np.ndarray, *, penalty: float,
           fuse_px: float, lost_px: float = 0.0, unseen: np.ndarray = NO_UNSEEN) -> Image:
        """The record, its numbers as float64 (one kernel signature whatever Python passed)."""
        return cls(det, start, offset, float(penalty), float(fuse_px), float(lost_px), unseen)


class RigArrays(NamedTuple):
    """Views encoded for the kernels (``core.rig.Rig.arrays``).

    kind : (V,) int64; P : (V, 3, 4) float64; K : (V, 3, 3) float64; dist : (V, 8) float64.
    bounds : (V, 4) float64, each view's region (u0, v0, u1, v1), full-frame pixels
        (``core.rig.Rig.regions``).
    """

    kind: np.ndarray
    P: np.ndarray
    K: np.ndarray
    dist: np.ndarray
    bounds: np.ndarray


class Bounds(NamedTuple):
    """Each DOF's range, (D,) float64 each: degrees (rotations) or model units (translations)."""

    lower: np.ndarray
    upper: np.ndarray


class SAParams(NamedTuple):
    """Simulated Annealing's settings (paper Table 1; ``core.anneal.AnnealParams``) and the
    attempt's (:func:`fit_attempt`).

    sigma : (D,) float64, s(H) of each DOF.  hist : (D, B) float64, bin probabilities, NaN rows
    for translations.  h_min : T_h.  n_end, n_l, n_tau : int, N_end, N_l, N_τ.  tau0, l0, c_l,
    c_tau : float, start temperature and step factor, their cooling factors.  eps : float, ε
    (px).  polish_every, patience, draws : int (:func:`anneal`).  huber_c : float, the
    refinement's least-squares radius (px) where it starts (:func:`refine`).
    refine_result : bool, restarts : int, search_edges : bool (:func:`fit_attempt`).
    """

    sigma: np.ndarray
    hist: np.ndarray
    h_min: float
    n_end: int
    n_l: int
    n_tau: int
    tau0: float
    l0: float
    c_l: float
    c_tau: float
    eps: float
    polish_every: int
    patience: int
    draws: int
    huber_c: float
    refine_result: bool
    restarts: int
    search_edges: bool


class Workspace(NamedTuple):
    """Scratch arrays of one posture's evaluation (:func:`workspace`).

    frames : (12·J,) joint frames.  sincos : (2·D,).  world : (M, 3) world markers.
    raw, fused : (V, M, 2) projections, apart and fused.  index : (M,) int64, dist : (M,),
    each marker's detection and distance (:func:`blob_error`).  claims : (N,) int64.
    hidden : (V, M) bool, the markers :func:`charged_unseen` marks.
    """

    frames: np.ndarray
    sincos: np.ndarray
    world: np.ndarray
    raw: np.ndarray
    fused: np.ndarray
    index: np.ndarray
    dist: np.ndarray
    claims: np.ndarray
    hidden: np.ndarray

class Assignment(NamedTuple):
    """What :func:`_residuals` chose for a posture in image mode, which its Jacobian keeps.

    valid : (G,) bool, the residual groups that count.  match : (G,) int64, each group's
    detection.  level : (V,) squared merge distance of each view's reading (px², -1: apart).
    raw : (V, M, 2) the posture's raw projections, which say who merges with whom.
    """

    valid: np.ndarray
    match: np.ndarray
    level: np.ndarray
    raw: np.ndarray


# ---- rotations -----------------------------------------------------------------------------


@njit(cache=True, nogil=True)
def euler_matrix(y: float, x: float, z: float, out: np.ndarray) -> None:
    """out = Ry(y)·Rx(x)·Rz(z), angles in radians."""
    cy, sy = math.cos(y), math.sin(y)
    cx, sx = math.cos(x), math.sin(x)
    cz, sz = math.cos(z), math.sin(z)
    out[0, 0] = cy * cz + sy * sx * sz
    out[0, 1] = -cy * sz + sy * sx * cz
    out[0, 2] = sy * cx
    out[1, 0] = cx * sz
    out[1, 1] = cx * cz
    out[1, 2] = -sx
    out[2, 0] = -sy * cz + cy * sx * sz
    out[2, 1] = sy * sz + cy * sx * cz
    out[2, 2] = cy * cx


# fdlibm's __kernel_sin / __kernel_cos coefficients, valid on |x| <= pi/4.
_S1, _S2, _S3 = -1.66666666666666324348e-01, 8.33333333332248946124e-03, -1.98412698298579493134e-04
_S4, _S5, _S6 = 2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10
_C1, _C2, _C3 = 4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05
_C4, _C5, _C6 = -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11


@njit(cache=True, nogil=True)
def sincos_deg(angle):
    """(sin, cos) of an angle in degrees, to a few ulp, without libm and without branches.

    Exact reduction by quarter turns (degrees make it exact), fdlibm's
    polynomials on |x| <= 45°, then the quadrant's swap and signs as selects.
    """
    n = np.floor(angle * (1.0 / 90.0) + 0.5)
    x = (angle - 90.0 * n) * DEG
    z = x * x
    s = x + x * z * (_S1 + z * (_S2 + z * (_S3 + z * (_S4 + z * (_S5 + z * _S6)))))
    c = 1.0 - 0.5 * z + z * z * (_C1 + z * (_C2 + z * (_C3 + z * (_C4 + z * (_C5 + z * _C6)))))
    quadrant = np.int64(n) & 3
    odd = (quadrant & 1) == 1
    sin = c if odd else s
    cos = s if odd else c
    sin_sign = -1.0 if quadrant >= 2 else 1.0
    cos_sign = -1.0 if (quadrant == 1 or quadrant == 2) else 1.0
    return sin_sign * sin, cos_sign * cos


@njit(cache=True, nogil=True)
def _mix(s, c, a0, a1, a2, b0, b1, b2):
    """Columns (a, b) of M·R for an elementary rotation R mixing them: (c·a + s·b, c·b − s·a).

    Rz mixes columns (0, 1), Rx (1, 2) and Ry (2, 0); 12 flops instead of a 3×3 product.
    """
    return (c * a0 + s * b0, c * a1 + s * b1, c * a2 + s * b2,
            c * b0 - s * a0, c * b1 - s * a1, c * b2 - s * a2)


# ---- forward kinematics ----------------------------------------------------------------------


@njit(cache=True, inline="always")
def joint_frames(q, kin, fr, sc) -> None:
    """World frame of every joint for posture ``q`` into ``fr`` (J·12), in topological order.

    W_j = W_parent · T(offset + t) · R(rest) · Ry · Rx · Rz; locked axes and
    identity rest orientations are skipped. ``sc`` (2·D) receives every DOF's
    sine and cosine (translations included: unused, harmless).
    """
    parent, offset, rest, rest_identity = kin.parent, kin.offset, kin.rest, kin.rest_identity
    rot_dof, trans_dof = kin.rot_dof, kin.trans_dof
    for i in range(q.shape[0]):
        sc[2 * i], sc[2 * i + 1] = sincos_deg(q[i])
    for k in range(parent.shape[0]):
        t0, t1, t2 = offset[k, 0], offset[k, 1], offset[k, 2]
        d = trans_dof[k, 0]
        if d >= 0:
            t0 += q[d]
        d = trans_dof[k, 1]
        if d >= 0:
            t1 += q[d]
        d = trans_dof[k, 2]
        if d >= 0:
            t2 += q[d]
        p = parent[k]
        if p < 0:
            x, y, z = t0, t1, t2
            b00, b01, b02, b10, b11, b12, b20, b21, b22 = 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0
        else:
            b = FRAME * p
            b00, b01, b02 = fr[b], fr[b + 1], fr[b + 2]
            b10, b11, b12 = fr[b + 3], fr[b + 4], fr[b + 5]
            b20, b21, b22 = fr[b + 6], fr[b + 7], fr[b + 8]
            x = fr[b + 9] + b00 * t0 + b01 * t1 + b02 * t2
            y = fr[b + 10] + b10 * t0 + b11 * t1 + b12 * t2
            z = fr[b + 11] + b20 * t0 + b21 * t1 + b22 * t2
        if rest_identity[k]:
            a00, a01, a02, a10, a11, a12, a20, a21, a22 = b00, b01, b02, b10, b11, b12, b20, b21, b22
        else:
            r00, r01, r02 = rest[k, 0, 0], rest[k, 0, 1], rest[k, 0, 2]
            r10, r11, r12 = rest[k, 1, 0], rest[k, 1, 1], rest[k, 1, 2]
            r20, r21, r22 = rest[k, 2, 0], rest[k, 2, 1], rest[k, 2, 2]
            a00 = b00 * r00 + b01 * r10 + b02 * r20
            a01 = b00 * r01 + b01 * r11 + b02 * r21
            a02 = b00 * r02 + b01 * r12 + b02 * r22
            a10 = b10 * r00 + b11 * r10 + b12 * r20
            a11 = b10 * r01 + b11 * r11 + b12 * r21
            a12 = b10 * r02 + b11 * r12 + b12 * r22
            a20 = b20 * r00 + b21 * r10 + b22 * r20
            a21 = b20 * r01 + b21 * r11 + b22 * r21
            a22 = b20 * r02 + b21 * r12 + b22 * r22
        d = rot_dof[k, 0]  # Ry mixes columns 2 and 0
        if d >= 0:
            a02, a12, a22, a00, a10, a20 = _mix(sc[2 * d], sc[2 * d + 1], a02, a12, a22, a00, a10, a20)
        d = rot_dof[k, 1]  # Rx mixes columns 1 and 2
        if d >= 0:
            a01, a11, a21, a02, a12, a22 = _mix(sc[2 * d], sc[2 * d + 1], a01, a11, a21, a02, a12, a22)
        d = rot_dof[k, 2]  # Rz mixes columns 0 and 1
        if d >= 0:
            a00, a10, a20, a01, a11, a21 = _mix(sc[2 * d], sc[2 * d + 1], a00, a10, a20, a01, a11, a21)
        o = FRAME * k
        fr[o], fr[o + 1], fr[o + 2], fr[o + 3], fr[o + 4], fr[o + 5] = a00, a01, a02, a10, a11, a12
        fr[o + 6], fr[o + 7], fr[o + 8], fr[o + 9], fr[o + 10], fr[o + 11] = a20, a21, a22, x, y, z


@njit(cache=True, inline="always")
def world_jacobian(fr, sc, kin, world, jac) -> None:
    """d(world marker)/dq into ``jac`` (M, 3, D) from the joint frames ``fr`` and DOF sines and
    cosines ``sc`` of :func:`joint_frames` and the world markers ``world`` (M, 3) they place.

    A joint's frame is W = B·R(rest)·Ry·Rx·Rz about its origin o, so an angle turns every
    point of its subtree about the axis its rotation leaves fixed: Ry about column 1 of
    B·R(rest), Rx about column 0 of B·R(rest)·Ry, Rz about column 2 of W, the first two read
    off W by undoing Rz, then Rx. A marker at x moves by (axis × (x − o))·π/180 per degree; a
    translation moves the joint's subtree along its column of B (the identity at the root).
    """
    parent, rot_dof, trans_dof = kin.parent, kin.rot_dof, kin.trans_dof
    jac[:] = 0.0
    for m in range(world.shape[0]):
        k = kin.marker_joint[m]
        while k >= 0:
            o = FRAME * k
            c0x, c0y, c0z = fr[o], fr[o + 3], fr[o + 6]
            c1x, c1y, c1z = fr[o + 1], fr[o + 4], fr[o + 7]
            c2x, c2y, c2z = fr[o + 2], fr[o + 5], fr[o + 8]
            rx, ry, rz = world[m, 0] - fr[o + 9], world[m, 1] - fr[o + 10], world[m, 2] - fr[o + 11]
            d = rot_dof[k, 2]
            if d >= 0:
                _turn(jac, m, d, c2x, c2y, c2z, rx, ry, rz)
                s, c = sc[2 * d], sc[2 * d + 1]  # undo Rz: columns 0 and 1 before it
                c0x, c0y, c0z, c1x, c1y, c1z = (c * c0x - s * c1x, c * c0y - s * c1y, c * c0z - s * c1z,
                                                s * c0x + c * c1x, s * c0y + c * c1y, s * c0z + c * c1z)
            d = rot_dof[k, 1]
            if d >= 0:
                _turn(jac, m, d, c0x, c0y, c0z, rx, ry, rz)
                s, c = sc[2 * d], sc[2 * d + 1]  # undo Rx: column 1 before it
                c1x, c1y, c1z = c * c1x - s * c2x, c * c1y - s * c2y, c * c1z - s * c2z
            d = rot_dof[k, 0]
            if d >= 0:
                _turn(jac, m, d, c1x, c1y, c1z, rx, ry, rz)
            p = parent[k]
            for a in range(3):
                d = trans_dof[k, a]
                if d >= 0:
                    for r in range(3):
                        jac[m, r, d] = (1.0 if r == a else 0.0) if p < 0 else fr[FRAME * p + 3 * r + a]
            k = p


@njit(cache=True, inline="always")
def _turn(jac, m, d, ax, ay, az, rx, ry, rz) -> None:
    """``jac[m, :, d]`` = (axis × r)·π/180: a point at r from the pivot, per degree about the axis."""
    jac[m, 0, d] = (ay * rz - az * ry) * DEG
    jac[m, 1, d] = (az * rx - ax * rz) * DEG
    jac[m, 2, d] = (ax * ry - ay * rx) * DEG


@njit(cache=True, nogil=True)
def forward_kinematics(q, kin, rot, pos) -> None:
    """World rotation ``rot`` (J,3,3) and origin ``pos`` (J,3) of every joint (topological order)."""
    J = kin.parent.shape[0]
    fr, sc = np.empty(FRAME * J), np.empty(2 * q.shape[0])
    joint_frames(q, kin, fr, sc)
    for k in range(J):
        for r in range(3):
            pos[k, r] = fr[FRAME * k + 9 + r]
            for c in range(3):
                rot[k, r, c] = fr[FRAME * k + 3 * r + c]


@njit(cache=True, inline="always")
def world_markers(fr, kin, out) -> None:
    """World position (M,3) of every marker from the joint frames ``fr``."""
    marker_joint, marker_pos = kin.marker_joint, kin.marker_pos
    for m in range(marker_joint.shape[0]):
        b = FRAME * marker_joint[m]
        x, y, z = marker_pos[m, 0], marker_pos[m, 1], marker_pos[m, 2]
        out[m, 0] = fr[b + 9] + fr[b] * x + fr[b + 1] * y + fr[b + 2] * z
        out[m, 1] = fr[b + 10] + fr[b + 3] * x + fr[b + 4] * y + fr[b + 5] * z
        out[m, 2] = fr[b + 11] + fr[b + 6] * x + fr[b + 7] * y + fr[b + 8] * z


@njit(cache=True, nogil=True)
def marker_positions_many(Q, kin):
    """World marker positions (T,M,3) for postures Q (T,D)."""
    J, M = kin.parent.shape[0], kin.marker_joint.shape[0]
    out = np.empty((Q.shape[0], M, 3))
    fr, sc = np.empty(FRAME * J), np.empty(2 * Q.shape[1])
    for t in range(Q.shape[0]):
        joint_frames(Q[t], kin, fr, sc)
        world_markers(fr, kin, out[t])
    return out


# ---- projection --------------------------------------------------------------------------------


@njit(cache=True, inline="always")
def _distort(K, dist, v, x, y):
    """OpenCV's pinhole model: normalised (x, y) → distorted → pixels through K (no skew).

    At or beyond a pole of the rational model (denominator ≤ 0, reachable with k4..k6 < 0)
    the model means nothing: ``BEHIND_CAMERA``, where OpenCV would divide by zero.
    """
    r2 = x * x + y * y
    denominator = 1.0 + r2 * (dist[v, 5] + r2 * (dist[v, 6] + r2 * dist[v, 7]))
    if not denominator > 0.0:
        return BEHIND_CAMERA, BEHIND_CAMERA
    radial = (1.0 + r2 * (dist[v, 0] + r2 * (dist[v, 1] + r2 * dist[v, 4]))) / denominator
    xd = x * radial + 2.0 * dist[v, 2] * x * y + dist[v, 3] * (r2 + 2.0 * x * x)
    yd = y * radial + dist[v, 2] * (r2 + 2.0 * y * y) + 2.0 * dist[v, 3] * x * y
    return K[v, 0, 0] * xd + K[v, 0, 2], K[v, 1, 1] * yd + K[v, 1, 2]


@njit(cache=True, inline="always")
def _project_raw(kind, P, K, dist, v, X0, X1, X2):
    """(u, v) by the view's projection formula, unbounded (may overflow for extreme rigs)."""
    h0 = P[v, 0, 0] * X0 + P[v, 0, 1] * X1 + P[v, 0, 2] * X2 + P[v, 0, 3]
    h1 = P[v, 1, 0] * X0 + P[v, 1, 1] * X1 + P[v, 1, 2] * X2 + P[v, 1, 3]
    if kind[v] == AFFINE:  # third row [0, 0, 0, 1]
        return h0, h1
    h2 = P[v, 2, 0] * X0 + P[v, 2, 1] * X1 + P[v, 2, 2] * X2 + P[v, 2, 3]
    if kind[v] == PINHOLE:
        if h2 <= 1e-12:
            return BEHIND_CAMERA, BEHIND_CAMERA
        return _distort(K, dist, v, h0 / h2, h1 / h2)
    if abs(h2) < 1e-300:
        return BEHIND_CAMERA, BEHIND_CAMERA
    return h0 / h2, h1 / h2


@njit(cache=True, inline="always")
def project_point(kind, P, K, dist, v, X0, X1, X2):
    """Pixel (u, v) of world point X in view v.

    Points behind a pinhole camera (or at infinity for a DLT matrix), and any
    projection at or beyond ``BEHIND_CAMERA`` pixels (an overflow, an inf or a
    NaN from extreme but finite rig numbers), go to ``BEHIND_CAMERA``: far from
    every detection, never inf or NaN, so Eq. 5 and the Metropolis step stay defined.
    """
    u, w = _project_raw(kind, P, K, dist, v, X0, X1, X2)
    if abs(u) < BEHIND_CAMERA and abs(w) < BEHIND_CAMERA:
        return u, w
    return BEHIND_CAMERA, BEHIND_CAMERA


@njit(cache=True, inline="always")
def project_markers(world, views, offset, out) -> None:
    """Pixel coordinates (V,M,2) of world markers (M,3) in ``views`` (``core.rig.RigArrays``),
    plus each view's 2D offset (V,2)."""
    kind, P, K, dist = views.kind, views.P, views.K, views.dist
    for v in range(kind.shape[0]):
        for m in range(world.shape[0]):
            u, w = project_point(kind, P, K, dist, v, world[m, 0], world[m, 1], world[m, 2])
            out[v, m, 0] = u + offset[v, 0]
            out[v, m, 1] = w + offset[v, 1]


@njit(cache=True, nogil=True)
def project_many(world, views):
    """Pixel coordinates (T,V,M,2) of world markers (T,M,3) in ``views``, no offsets."""
    V = views.kind.shape[0]
    out = np.empty((world.shape[0], V, world.shape[1], 2))
    zero = np.zeros((V, 2))
    for t in range(world.shape[0]):
        project_markers(world[t], views, zero, out[t])
    return out


@njit(cache=True, inline="always")
def fuse_projections(raw, fuse_px, out) -> None:
    """Markers as the camera images them: closer than ``fuse_px`` they are one blob.

    Each projection (V,M,2) is replaced by the mean of all projections of its
    view within ``fuse_px`` of it (itself included): two overlapping discs give
    one detection at their common centroid, so the true posture of a fused
    frame is again a zero of the error.
    """
    f2 = fuse_px * fuse_px
    for v in range(raw.shape[0]):
        for m in range(raw.shape[1]):
            su, sv, n = 0.0, 0.0, 0.0
            for k in range(raw.shape[1]):
                du, dv = raw[v, k, 0] - raw[v, m, 0], raw[v, k, 1] - raw[v, m, 1]
                w = 1.0 if du * du + dv * dv < f2 else 0.0
                su += w * raw[v, k, 0]
                sv += w * raw[v, k, 1]
                n += w
            out[v, m, 0], out[v, m, 1] = su / n, sv / n


@njit(cache=True, nogil=True)
def workspace(kin, views, D, N):
    """A :class:`Workspace` for model ``kin``, ``views``, ``D`` DOFs and ``N`` detections."""
    J, M, V = kin.parent.shape[0], kin.marker_joint.shape[0], views.kind.shape[0]
    return Workspace(np.empty(FRAME * J), np.empty(2 * D), np.empty((M, 3)), np.empty((V, M, 2)),
                     np.empty((V, M, 2)), np.empty(M, dtype=np.int64), np.empty(M),
                     np.empty(N, dtype=np.int64), np.empty((V, M), dtype=np.bool_))


@njit(cache=True, inline="always")
def project_posture(q, kin, views, offset, fuse_px, work) -> None:
    """Raw projections (V,M,2) of posture ``q`` into ``work.raw``, fused ones into ``work.fused``.

    ``offset`` and ``fuse_px`` come apart from their :class:`Image`: SA's inner loop takes
    them out of it once, not at every iteration (reference counting).
    """
    fr, sc, world, raw, fused = work.frames, work.sincos, work.world, work.raw, work.fused
    joint_frames(q, kin, fr, sc)
    world_markers(fr, kin, world)
    project_markers(world, views, offset, raw)
    if fuse_px > 0.0:
        fuse_projections(raw, fuse_px, fused)


@njit(cache=True, inline="always")
def charged_unseen(unseen, bounds, raw, hidden, fuse_px):
    """The (V, M) markers the objective charges as unseen, written into ``hidden`` and
    returned: those ``unseen`` marks ((0, 0): none), and each marker whose raw projection
    ``raw`` (V, M, 2) lies outside its view's region ``bounds`` (V, 4), u0 <= u < u1 and
    v0 <= v < v1 (``core.rig.RigArrays.bounds``; infinite where not known), by more than
    half a marker's diameter (``fuse_px`` / :data:`FUSION_DIAMETERS`; closer, part of its
    disc shows inside). A marker out of the frame cannot have been detected; charged its
    distance to the nearest blob in the frame, it would be pulled back in, and its limb
    with it."""
    r = 0.5 * fuse_px / FUSION_DIAMETERS
    for v in range(raw.shape[0]):
        u0, v0, u1, v1 = bounds[v, 0] - r, bounds[v, 1] - r, bounds[v, 2] + r, bounds[v, 3] + r
        for m in range(raw.shape[1]):
            u, w = raw[v, m, 0], raw[v, m, 1]
            hidden[v, m] = ((unseen.shape[0] > 0 and unseen[v, m])
                            or not (u0 <= u < u1 and v0 <= w < v1))
    return hidden


# ---- Eq. 5 -------------------------------------------------------------------------------


@njit(cache=True, inline="always")
def eq5(proj, det, start, penalty, limit, unseen):
    """Eq. 5: sum over views and markers of the distance to the nearest detection.

    proj (V,M,2) pixels; det (N,3) detections of all views (u, v, and the merged
    flag :func:`blob_error` reads), view v in ``det[start[v]:start[v+1]]``. A view
    without detections adds ``penalty`` per marker, and so does a marker
    ``unseen`` (V,M) marks (empty: none). Stops
    summing after a view once the sum exceeds ``limit`` and returns the partial
    sum: the SA only needs to know that a proposal is rejected.
    """
    total = 0.0
    for v in range(proj.shape[0]):
        a, b = start[v], start[v + 1]
        if a == b:
            total += penalty * proj.shape[1]
            continue
        for m in range(proj.shape[1]):
            if unseen.shape[0] > 0 and unseen[v, m]:
                total += penalty
                continue
            pu, pv = proj[v, m, 0], proj[v, m, 1]
            best = np.inf
            for c in range(a, b):
                du, dv = pu - det[c, 0], pv - det[c, 1]
                d2 = du * du + dv * dv
                best = d2 if d2 < best else best
            total += math.sqrt(best)
        if total > limit:
            return total
    return total


@njit(cache=True, inline="always")
def _nearest(u, w, det, a, b):
    """(squared distance, index) of the detection of ``det[a:b]`` nearest to (u, w)."""
    best, index = np.inf, -1
    for c in range(a, b):
        du, dv = u - det[c, 0], w - det[c, 1]
        d2 = du * du + dv * dv
        nearer = d2 < best
        best = d2 if nearer else best
        index = c if nearer else index
    return best, index


@njit(cache=True, inline="always")
def _match_view(proj, v, det, a, b, index, dist, unseen, penalty) -> float:
    """Each marker's nearest detection in view v (``index``, ``dist``); returns their sum.

    A marker ``unseen`` marks claims nothing (index -1) and costs ``penalty``.
    """
    total = 0.0
    for m in range(proj.shape[1]):
        if unseen.shape[0] > 0 and unseen[v, m]:
            index[m], dist[m] = -1, penalty
        else:
            d2, c = _nearest(proj[v, m, 0], proj[v, m, 1], det, a, b)
            index[m], dist[m] = c, math.sqrt(d2)
        total += dist[m]
    return total


@njit(cache=True, inline="always")
def _unexplained(raw, proj, v, det, a, b, index, claims, reach2) -> float:
    """Charge of the detections of view v no marker claims, next to markers that share a blob.

    Two markers put on one blob leave a neighbouring blob unexplained (the paper's
    Fig. 9, posture B; or a merged reading that squeezes two markers onto one
    blob): such a detection, within ``sqrt(reach2)`` (``fuse_px``) of where a
    marker sharing a blob projects itself (``raw``), is charged its distance to
    the nearest marker of the reading (``proj``). Other unclaimed detections
    (ghosts) cost nothing, as in Eq. 5, nor do those another part explains (``det``'s
    fourth column, where it has one: :class:`Image`). Two markers sharing a blob whose
    area says it may be two merged markers (``det[:, 2]``; any blob where areas are
    unknown) are what the detector saw, not a squeeze: a detection next to them is a ghost
    and costs nothing, where charged it would make the true posture of a fused pair lose to
    a wrong one. A third marker on such a blob is a squeeze again.
    """
    for c in range(a, b):
        claims[c] = 0
    for m in range(proj.shape[1]):
        if index[m] >= 0:
            claims[index[m]] += 1
    total = 0.0
    elsewhere = det.shape[1] > 3
    for c in range(a, b):
        if claims[c] > 0 or (elsewhere and det[c, 3] > 0.0):
            continue
        for m in range(raw.shape[1]):
            shared = claims[index[m]] if index[m] >= 0 else 0
            if shared < 2 or (shared == 2 and det[index[m], 2] > 0.0):
                continue
            du, dv = det[c, 0] - raw[v, m, 0], det[c, 1] - raw[v, m, 1]
            if du * du + dv * dv < reach2:
                total += math.sqrt(_nearest(det[c, 0], det[c, 1], proj[v], 0, proj.shape[1])[0])
                break
    return total


@njit(cache=True, inline="always")
def _lose_worst(total, dist, lost_px):
    """``total`` with the largest of ``dist`` charged ``lost_px`` instead, if that is less.

    A plain loop, after the ``lost_px`` test: cheaper than ``np.max`` in SA's inner loop,
    most of all when no marker may be lost.
    """
    if not lost_px > 0.0:
        return total
    worst = dist[0]
    for m in range(1, dist.shape[0]):
        worst = dist[m] if dist[m] > worst else worst
    return total - (worst - lost_px) if lost_px < worst else total


@njit(cache=True, inline="always")
def _view_reading(raw, fused, v, det, a, b, penalty, fuse_px, lost_px, unseen, index, dist, claims):
    """(cost, level) of view v: its markers imaged apart (level -1), or with the pairs closer
    than squared distance ``level`` (px²) merged (kept in ``fused``).

    Whether the detector merged two close markers depends on their distance, size
    and the threshold, and it merges closer pairs first: the view is read apart, then
    with the pairs closer than each pair distance below ``fuse_px`` merged (nested
    readings, the last merging every pair closer than ``fuse_px``), and the reading
    that explains it best is kept. Read all merged or all apart, a view holding a merged
    pair and a pair imaged apart within ``fuse_px`` would charge the true posture for
    one of them, and the fit would pull those markers off their blobs. Only distances
    at a pair with a large detection near its midpoint are read, then the full merge;
    merged only if the view shows a detection large enough to be merged markers
    (``det[:, 2]``, ``core.error.Detections.kernel_points``): with one view, merging would
    otherwise let a wrong posture squeeze two markers onto one blob. With
    ``lost_px`` > 0 either reading may lose its worst marker, charged ``lost_px``
    instead of its distance (an occluded marker). ``index``, ``dist``, ``claims``: scratch
    (:class:`Workspace`'s last three), passed apart: taking them out of the tuple in SA's
    inner loop costs reference counting at every iteration.
    """
    reach2 = fuse_px * fuse_px
    apart = _lose_worst(_match_view(raw, v, det, a, b, index, dist, unseen, penalty), dist, lost_px)
    apart += _unexplained(raw, raw, v, det, a, b, index, claims, reach2)
    differs = large = False
    for m in range(raw.shape[1]):
        differs = differs or fused[v, m, 0] != raw[v, m, 0] or fused[v, m, 1] != raw[v, m, 1]
    for c in range(a, b):
        large = large or det[c, 2] > 0.0
    if not (differs and large):
        return apart, -1.0
    return _nested_reading(raw, fused, v, det, a, b, reach2, lost_px, apart, unseen, index, dist,
                           claims)


@njit(cache=True, nogil=True)
def _nested_reading(raw, fused, v, det, a, b, reach2, lost_px, apart, unseen, index, dist, claims):
    """:func:`_view_reading` of view v past its all-apart reading (cost ``apart``, ``index`` and
    ``dist`` as its :func:`_match_view` left them), whose full merge (``fused``) differs: the
    nested merged readings, the best kept in ``fused`` if it beats ``apart``; returns (cost,
    its squared merge distance, or -1 where apart is best). Compiled once
    and called, not inlined: :func:`_view_reading` is inlined wherever the objective is, and
    this loop is only taken in views with merged-looking blobs."""
    M = raw.shape[1]
    close = np.empty(M, dtype=np.bool_)  # markers the full merge moves: only they ever move
    for m in range(M):
        close[m] = fused[v, m, 0] != raw[v, m, 0] or fused[v, m, 1] != raw[v, m, 1]
        fused[v, m, 0], fused[v, m, 1] = raw[v, m, 0], raw[v, m, 1]
    best, best_level, last = apart, -1.0, -1.0
    level = _next_level(raw, v, det, a, b, close, -1.0, reach2)
    while level >= 0.0:
        total = _merge_closer(raw, fused, v, level, close, det, a, b, index, dist, unseen)
        merged = _lose_worst(total, dist, lost_px) + _unexplained(raw, fused, v, det, a, b, index,
                                                                  claims, reach2)
        if merged < best:
            best, best_level = merged, level
        last, level = level, _next_level(raw, v, det, a, b, close, level, reach2)
    if best_level < 0.0:
        return apart, -1.0
    if best_level != last:
        _merge_closer(raw, fused, v, best_level, close, det, a, b, index, dist, unseen)
    return best, best_level


@njit(cache=True, inline="always")
def _next_level(raw, v, det, a, b, close, above, reach2) -> float:
    """The next squared distance above ``above`` at which view v may be read with more of its
    markers merged, or -1: the least distance between two ``close`` markers below ``reach2``
    whose midpoint has a detection large enough to be merged markers (``det[a:b]``) within
    ``sqrt(reach2)``, else the greatest below ``reach2`` (every close pair merged)."""
    level, top = -1.0, -1.0
    for m in range(raw.shape[1]):
        if not close[m]:
            continue
        for k in range(m + 1, raw.shape[1]):
            if not close[k]:
                continue
            du, dv = raw[v, k, 0] - raw[v, m, 0], raw[v, k, 1] - raw[v, m, 1]
            d2 = du * du + dv * dv
            if not above < d2 < reach2:
                continue
            top = d2 if d2 > top else top
            if level >= 0.0 and d2 >= level:
                continue
            mu, mv = 0.5 * (raw[v, k, 0] + raw[v, m, 0]), 0.5 * (raw[v, k, 1] + raw[v, m, 1])
            for c in range(a, b):
                eu, ev = det[c, 0] - mu, det[c, 1] - mv
                if det[c, 2] > 0.0 and eu * eu + ev * ev < reach2:
                    level = d2
                    break
    return level if level >= 0.0 else top


@njit(cache=True, nogil=True)
def _merged(raw, anchor, v, m, level):
    """Where marker m merged with the markers within squared distance ``level`` of it at
    ``anchor`` (V, M, 2), itself included, images in view v: the mean of their ``raw``
    projections (V, M, 2), (u, v) px."""
    su, sv, n = 0.0, 0.0, 0.0
    for k in range(raw.shape[1]):
        du, dv = anchor[v, k, 0] - anchor[v, m, 0], anchor[v, k, 1] - anchor[v, m, 1]
        w = 1.0 if du * du + dv * dv <= level else 0.0
        su += w * raw[v, k, 0]
        sv += w * raw[v, k, 1]
        n += w
    return su / n, sv / n


@njit(cache=True, inline="always")
def _merge_closer(raw, fused, v, level, close, det, a, b, index, dist, unseen) -> float:
    """View v of ``fused`` read with the markers closer than squared distance ``level``
    merged (each ``close`` marker at the mean of those within it, itself included, as
    :func:`fuse_projections`), the markers that moved matched again (``index``, ``dist``,
    as :func:`_match_view` left them for ``fused``'s previous reading); returns their sum."""
    for m in range(raw.shape[1]):
        if not close[m]:
            continue
        u, w_ = _merged(raw, raw, v, m, level)
        if u == fused[v, m, 0] and w_ == fused[v, m, 1]:
            continue
        fused[v, m, 0], fused[v, m, 1] = u, w_
        if not (unseen.shape[0] > 0 and unseen[v, m]):
            d2, c = _nearest(u, w_, det, a, b)
            index[m], dist[m] = c, math.sqrt(d2)
    total = 0.0
    for m in range(raw.shape[1]):
        total += dist[m]
    return total


@njit(cache=True, inline="always")
def blob_error(raw, fused, det, start, penalty, fuse_px, lost_px, limit, index, dist, claims, unseen):
    """The objective: Eq. 5, or with ``fuse_px`` > 0 Eq. 5 read as the blobs a camera shows.

    ``fuse_px`` <= 0: exactly :func:`eq5` on the raw projections (the paper).
    ``fuse_px`` > 0: every view is read as its markers imaged apart, or with its pairs
    closer than some distance up to ``fuse_px`` merged into one blob at their centroid,
    whichever explains the view best (:func:`_view_reading`; a detector merges two discs
    up to ~1.3 diameters apart, depending on the threshold); each reading is Eq. 5 plus
    the charge of :func:`_unexplained` detections. A view without detections adds ``penalty``
    per marker, and so does a marker ``unseen`` (V,M) marks (empty: none);
    ``lost_px`` > 0 lets every view lose one marker (:func:`_view_reading`).
    ``index``, ``dist``, ``claims``: scratch as :func:`_view_reading`'s. Stops summing once
    above ``limit`` (between views), as :func:`eq5`.
    """
    if fuse_px <= 0.0:
        return eq5(raw, det, start, penalty, limit, unseen)
    total = 0.0
    for v in range(raw.shape[0]):
        a, b = start[v], start[v + 1]
        if a == b:
            total += penalty * raw.shape[1]
            continue
        total += _view_reading(raw, fused, v, det, a, b, penalty, fuse_px, lost_px, unseen,
                               index, dist, claims)[0]
        if total > limit:
            return total
    return total


@njit(cache=True, nogil=True)
def posture_error(q, kin, views, image):
    """The objective (:func:`blob_error`) of posture ``q`` on ``image`` (:class:`Image`); plain
    Eq. 5 with ``image.fuse_px`` and ``image.lost_px`` 0."""
    work = workspace(kin, views, q.shape[0], image.det.shape[0])
    return _evaluate(q, kin, views, image, np.inf, work)


@njit(cache=True, nogil=True)
def plain_error(q, kin, views, image):
    """The Eq. 5 a fit reports (``error_px``, FORMATS §3) of posture ``q`` on ``image``: the
    raw projections' distances to their nearest detections, ``image.fuse_px`` and
    ``image.lost_px`` not read, a view without detections and a marker ``image.unseen``
    marks charged ``image.penalty``, and a marker outside its view's region charged its
    nearest detection all the same (``views.bounds`` not read: the format's sum is over
    every marker)."""
    work = workspace(kin, views, q.shape[0], image.det.shape[0])
    _project(q, kin, views, image.offset, 0.0, work)
    return eq5(work.raw, image.det, image.start, image.penalty, np.inf, image.unseen)


@njit(cache=True, nogil=True)
def beyond_edges(q, kin, views, image):
    """(V, M) bool: the raw projections of posture ``q`` in views with detections that the
    objective charges as unseen beyond their view's region (:func:`charged_unseen`, half a
    marker's diameter read from ``image.fuse_px``)."""
    return _beyond(q, kin, views, image, workspace(kin, views, q.shape[0], image.det.shape[0]))


@njit(cache=True, nogil=True)
def outside_error(q, kin, views, image):
    """(how many, pixels): the projections :func:`beyond_edges` marks, and the sum of their
    distances to their nearest detections (what they add to :func:`plain_error`)."""
    work = workspace(kin, views, q.shape[0], image.det.shape[0])
    beyond = _beyond(q, kin, views, image, work)
    count, px = 0, 0.0
    for v in range(beyond.shape[0]):
        a, b = image.start[v], image.start[v + 1]
        for m in range(beyond.shape[1]):
            if beyond[v, m]:
                count += 1
                px += math.sqrt(_nearest(work.raw[v, m, 0], work.raw[v, m, 1], image.det, a, b)[0])
    return count, px


@njit(cache=True, inline="always")
def _beyond(q, kin, views, image, work):
    """:func:`beyond_edges` into ``work.hidden``, the raw projections left in ``work.raw``."""
    _project(q, kin, views, image.offset, 0.0, work)
    hidden = charged_unseen(_no_unseen(), views.bounds, work.raw, work.hidden, image.fuse_px)
    for v in range(hidden.shape[0]):
        if image.start[v] == image.start[v + 1]:
            for m in range(hidden.shape[1]):
                hidden[v, m] = False
    return hidden


@njit(cache=True, inline="always")
def _evaluate(q, kin, views, image, limit, work):
    """The objective (:func:`blob_error`, summed up to ``limit``) of posture ``q``, projected
    into ``work`` (:class:`Workspace`) by the plain calls :func:`_project` and
    :func:`_objective`; inlined, as a thin wrapper (see the module's docstring)."""
    _project(q, kin, views, image.offset, image.fuse_px, work)
    return _objective(views, image, limit, work)


@njit(cache=True, nogil=True)
def _project(q, kin, views, offset, fuse_px, work) -> None:
    """:func:`project_posture` as a plain call, as :func:`_objective`."""
    project_posture(q, kin, views, offset, fuse_px, work)


@njit(cache=True, nogil=True)
def _objective(views, image, limit, work):
    """:func:`blob_error` of the projections in ``work`` as a plain call, compiled once for the
    kernels that evaluate it outside SA's inner loop (numba types an inlined helper again at
    every call site)."""
    return blob_error(work.raw, work.fused, image.det, image.start, image.penalty, image.fuse_px,
                      image.lost_px, limit, work.index, work.dist, work.claims,
                      charged_unseen(image.unseen, views.bounds, work.raw, work.hidden, image.fuse_px))


@njit(cache=True, nogil=True)
def _with(image, fuse_px, lost_px, unseen):
    """``image`` charged otherwise: its detections with these ``fuse_px``, ``lost_px``, ``unseen``."""
    return Image(image.det, image.start, image.offset, image.penalty, fuse_px, lost_px, unseen)


@njit(cache=True, inline="always")
def _copy(dst, src) -> None:
    """``dst[:] = src`` for two 1-D float64 arrays of one length, as a loop (2-D: their
    ``ravel()``): numba's slice assignment compiles its shape-mismatch message (string
    formatting, 1.5 s or more) in every process that compiles a kernel using it, for every
    number of dimensions. Inlined: SA copies at every accepted proposal."""
    for i in range(src.shape[0]):
        dst[i] = src[i]


@njit(cache=True, nogil=True)
def _no_unseen():
    """No marker unseen: the empty (0, 0) mask of the type Python passes (``NO_UNSEEN``)."""
    return np.zeros((0, 0), dtype=np.bool_)


@njit(cache=True, nogil=True)
def _no_targets():
    """Image mode for :func:`refine`: empty (0, 3) targets of the type Python passes (``NO_TARGETS``)."""
    return np.zeros((0, 3))


# ---- random numbers -------------------------------------------------------------------------


@njit(cache=True, nogil=True)
def _rotl(x, k):
    return (x << np.uint64(k)) | (x >> np.uint64(64 - k))


@njit(cache=True, inline="always")
def next_uniform(s) -> float:
    """xoshiro256** step on state ``s`` (4 uint64): a float64 uniform in [0, 1)."""
    result = _rotl(s[1] * np.uint64(5), 7) * np.uint64(9)
    t = s[1] << np.uint64(17)
    s[2] ^= s[0]
    s[3] ^= s[1]
    s[1] ^= s[2]
    s[0] ^= s[3]
    s[2] ^= t
    s[3] = _rotl(s[3], 45)
    return float(result >> np.uint64(11)) * (1.0 / 9007199254740992.0)


# ---- local refinement ---------------------------------------------------------------------------


@njit(cache=True, nogil=True)
def _residuals(q, kin, views, image, targets, work, res, chosen):
    """Residual groups ``res`` of posture ``q`` on ``image``, and what they were chosen by,
    ``chosen`` (:class:`Assignment`; ``chosen.valid``: the groups that count).

    Image mode (no ``targets``, ``res`` (V·M, 2)): group v·M + m is marker m's
    position in view v (raw, or merged where :func:`blob_error` reads the view so)
    minus its nearest detection; a view without detections does not count, nor
    does a marker ``unseen`` marks. :func:`refine`'s Jacobian (:func:`_jacobian`) keeps
    ``chosen``: each group its detection, each marker the markers it merged with. Target
    mode (``targets`` and ``res`` (M, 3)): group m is world marker m minus its target
    (inverse kinematics); a marker whose target is NaN does not count.
    """
    valid, match, level, anchor = chosen
    if targets.shape[0] > 0:
        fr, sc, world = work.frames, work.sincos, work.world
        joint_frames(q, kin, fr, sc)
        world_markers(fr, kin, world)
        for m in range(world.shape[0]):
            valid[m] = not math.isnan(targets[m, 0])
            for a in range(3):
                res[m, a] = world[m, a] - targets[m, a] if valid[m] else 0.0
        return
    det, start, penalty, fuse_px = image.det, image.start, image.penalty, image.fuse_px
    project_posture(q, kin, views, image.offset, fuse_px, work)
    raw, fused, index, dist, claims = work.raw, work.fused, work.index, work.dist, work.claims
    unseen = charged_unseen(image.unseen, views.bounds, raw, work.hidden, fuse_px)
    V, M = raw.shape[0], raw.shape[1]
    for v in range(V):
        a, b = start[v], start[v + 1]
        level[v] = -1.0
        if a < b and fuse_px > 0.0:
            level[v] = _view_reading(raw, fused, v, det, a, b, penalty, fuse_px, 0.0, unseen,
                                     index, dist, claims)[1]
        if a < b:
            _match_view(fused if level[v] >= 0.0 else raw, v, det, a, b, index, dist, unseen, penalty)
        pos = fused if level[v] >= 0.0 else raw
        for m in range(M):
            g = v * M + m
            match[g], valid[g] = index[m], a < b and index[m] >= 0
            anchor[v, m, 0], anchor[v, m, 1] = raw[v, m, 0], raw[v, m, 1]
            res[g, 0] = pos[v, m, 0] - det[match[g], 0] if valid[g] else 0.0
            res[g, 1] = pos[v, m, 1] - det[match[g], 1] if valid[g] else 0.0


@njit(cache=True, nogil=True)
def projection_jacobians(world, views, out) -> None:
    """d(pixel)/d(world point) (V, M, 2, 3) of every marker ``world`` (M, 3) in ``views``:
    the derivative of :func:`project_point`'s formula, OpenCV's lens distortion included;
    zero where the point projects to ``BEHIND_CAMERA``."""
    kind, P, K, dist = views.kind, views.P, views.K, views.dist
    out[:] = 0.0
    for v in range(kind.shape[0]):
        for m in range(world.shape[0]):
            X0, X1, X2 = world[m, 0], world[m, 1], world[m, 2]
            if project_point(kind, P, K, dist, v, X0, X1, X2)[0] == BEHIND_CAMERA:
                continue
            if kind[v] == AFFINE:
                for j in range(3):
                    out[v, m, 0, j], out[v, m, 1, j] = P[v, 0, j], P[v, 1, j]
                continue
            h2 = P[v, 2, 0] * X0 + P[v, 2, 1] * X1 + P[v, 2, 2] * X2 + P[v, 2, 3]
            x = (P[v, 0, 0] * X0 + P[v, 0, 1] * X1 + P[v, 0, 2] * X2 + P[v, 0, 3]) / h2
            y = (P[v, 1, 0] * X0 + P[v, 1, 1] * X1 + P[v, 1, 2] * X2 + P[v, 1, 3]) / h2
            # d(pixel)/d(x, y): the identity for a DLT matrix, the distortion's through K for a pinhole
            xx, xy, yx, yy = 1.0, 0.0, 0.0, 1.0
            if kind[v] == PINHOLE:
                xx, xy, yx, yy = _distortion_jacobian(K, dist, v, x, y)
            for j in range(3):
                dx, dy = (P[v, 0, j] - x * P[v, 2, j]) / h2, (P[v, 1, j] - y * P[v, 2, j]) / h2
                out[v, m, 0, j] = xx * dx + xy * dy
                out[v, m, 1, j] = yx * dx + yy * dy


@njit(cache=True, inline="always")
def _distortion_jacobian(K, dist, v, x, y):
    """d(u, v)/d(x, y) of :func:`_distort` at the normalised point (x, y): (du/dx, du/dy,
    dv/dx, dv/dy), pixels per unit."""
    r2 = x * x + y * y
    k1, k2, p1, p2, k3, k4, k5, k6 = (dist[v, 0], dist[v, 1], dist[v, 2], dist[v, 3], dist[v, 4],
                                      dist[v, 5], dist[v, 6], dist[v, 7])
    num, den = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3)), 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
    radial = num / den
    slope = ((k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)) * den - num * (k4 + r2 * (2.0 * k5 + 3.0 * k6 * r2))) / (
        den * den)  # d(radial)/d(r2)
    cross = 2.0 * x * y * slope + 2.0 * p1 * x + 2.0 * p2 * y  # d(xd)/dy = d(yd)/dx
    fx, fy = K[v, 0, 0], K[v, 1, 1]
    return (fx * (radial + 2.0 * x * x * slope + 2.0 * p1 * y + 6.0 * p2 * x), fx * cross,
            fy * cross, fy * (radial + 2.0 * y * y * slope + 6.0 * p1 * y + 2.0 * p2 * x))


@njit(cache=True, inline="always")
def _jacobian(kin, views, targets, work, chosen, wj, dp, view_jac, jac) -> None:
    """d(residual)/dq of :func:`_residuals` under ``chosen`` into ``jac`` (G, C, D), at the
    posture whose joint frames, sines and cosines and world markers ``work`` holds.

    Target mode: the markers' world Jacobian (:func:`world_jacobian`). Image mode: that
    Jacobian (into ``wj`` (M, 3, D)) through each marker's projection
    (:func:`projection_jacobians`), merged as ``chosen`` merges the view (each marker the
    mean of those within ``chosen.level`` of it at ``chosen.raw``, as :func:`_merged`;
    ``dp`` (V, M, 2, 3) and ``view_jac`` (M, 2, D) scratch). No evaluation: differencing
    every DOF cost D of them.
    """
    fr, sc, world = work.frames, work.sincos, work.world
    world_jacobian(fr, sc, kin, world, jac if targets.shape[0] > 0 else wj)
    if targets.shape[0] > 0:
        return
    V, M, D = views.kind.shape[0], world.shape[0], jac.shape[2]
    projection_jacobians(world, views, dp)
    for v in range(V):
        for m in range(M):
            for r in range(2):
                d0, d1, d2 = dp[v, m, r, 0], dp[v, m, r, 1], dp[v, m, r, 2]
                for i in range(D):
                    view_jac[m, r, i] = d0 * wj[m, 0, i] + d1 * wj[m, 1, i] + d2 * wj[m, 2, i]
        level, raw = chosen.level[v], chosen.raw
        for m in range(M):
            g, n = v * M + m, 1.0
            for r in range(2):
                for i in range(D):
                    jac[g, r, i] = view_jac[m, r, i]
            if level < 0.0:  # read apart
                continue
            for k in range(M):
                du, dv = raw[v, k, 0] - raw[v, m, 0], raw[v, k, 1] - raw[v, m, 1]
                if k != m and du * du + dv * dv <= level:
                    n += 1.0
                    for r in range(2):
                        for i in range(D):
                            jac[g, r, i] += view_jac[k, r, i]
            for r in range(2):
                for i in range(D):
                    jac[g, r, i] /= n


@njit(cache=True, nogil=True)
def _assignment(G, V, M):
    """An :class:`Assignment` for ``G`` residual groups, ``V`` views, ``M`` markers."""
    return Assignment(np.zeros(G, dtype=np.bool_), np.zeros(G, dtype=np.int64), np.zeros(V),
                      np.zeros((V, M, 2)))


@njit(cache=True, inline="always")
def _keep(dst, src) -> None:
    """``dst`` (:class:`Assignment`) takes ``src``'s values."""
    for g in range(src.valid.shape[0]):
        dst.valid[g], dst.match[g] = src.valid[g], src.match[g]
    _copy(dst.level, src.level)
    _copy(dst.raw.ravel(), src.raw.ravel())


@njit(cache=True, inline="always")
def _norm(res, g):
    acc = 0.0
    for a in range(res.shape[1]):
        acc += res[g, a] * res[g, a]
    return math.sqrt(acc)


@njit(cache=True, nogil=True)
def _huber_cost(res, valid, c):
    total = 0.0
    for g in range(res.shape[0]):
        if valid[g]:
            e = _norm(res, g)
            total += 0.5 * e * e if e <= c else c * (e - 0.5 * c)
    return total


@njit(cache=True, nogil=True)
def _tightens(res, valid, c) -> bool:
    """Whether :func:`refine`, converged at Huber radius ``c`` (px), goes on at
    :data:`MIN_RADIUS_PX`: some residual group of ``res`` (``valid`` ones) is longer than
    ``c`` (an outlier pulling at full strength) while their median length is under
    :data:`TIGHTEN_BELOW` of ``c`` (most residuals nearly free against it). With every
    residual within ``c`` the loss is least squares and a smaller radius changes nothing;
    with residuals of the radius' order (sliding skin markers) the radius stays.
    """
    n, longest = 0, 0.0
    lengths = np.empty(res.shape[0])
    for g in range(res.shape[0]):
        if valid[g]:
            lengths[n] = _norm(res, g)
            longest = max(longest, lengths[n])
            n += 1
    return MIN_RADIUS_PX < c < longest and np.median(lengths[:n]) < TIGHTEN_BELOW * c


@njit(cache=True, nogil=True)
def solve_spd(A, b):
    """x with A·x = b for a small symmetric positive-definite A, by Cholesky.

    The damped normal equations of :func:`refine` are D×D with D the number of
    DOFs; a direct solve avoids LAPACK (and SciPy, which numba needs for it).
    """
    n = b.shape[0]
    L, x = np.empty((n, n)), np.empty(n)
    _cholesky_solve(A, b, L, x)
    return x


@njit(cache=True, nogil=True)
def _cholesky_solve(A, b, L, x) -> None:
    """x = A⁻¹·b by Cholesky into the caller's scratch ``L`` (n,n); ``x`` (n,) also holds y."""
    n = b.shape[0]
    for i in range(n):
        for j in range(i + 1):
            acc = A[i, j]
            for k in range(j):
                acc -= L[i, k] * L[j, k]
            if i == j:
                L[i, i] = math.sqrt(max(acc, 1e-300))
            else:
                L[i, j] = acc / L[j, j]
    for i in range(n):
        acc = b[i]
        for k in range(i):
            acc -= L[i, k] * x[k]
        x[i] = acc / L[i, i]
    for i in range(n - 1, -1, -1):
        acc = x[i]
        for k in range(i + 1, n):
            acc -= L[k, i] * x[k]
        x[i] = acc / L[i, i]


@njit(cache=True, nogil=True)
def refine(q0, bounds, kin, views, image, huber_c, max_iter, targets):
    """Levenberg–Marquardt on the Huber loss of residual groups (:func:`_residuals`), within
    ``bounds`` (:class:`Bounds`).

    Image mode (``targets`` of shape (0, 3)): nearest detections are re-chosen at
    every evaluation, so this polishes the basin SA found (sub-pixel) without
    committing to marker labels. Residuals below the Huber radius are fitted
    by least squares (efficient for detection noise), larger ones by their
    length (robust to fused or missing markers, as Eq. 5 is); ``image.lost_px`` is not
    read, markers ``image.unseen`` marks count nothing. The radius starts at ``huber_c``
    pixels; once LM converges, it goes on at :data:`MIN_RADIUS_PX` where an outlier lies
    beyond the radius and most residuals well within it (:func:`_tightens`): with
    residuals far below the radius every one of them is nearly free at first order, and one
    marker hidden from a camera, lying a few pixels from another blob, pulls the posture
    off Eq. 5's minimum (docs/ENGINE_NOTES.md). Target mode (``targets`` (M, 3)):
    inverse kinematics onto world marker positions, NaN rows left out (``image`` not read;
    radius ``huber_c``).
    Jacobian (:func:`_jacobian`) under the assignment of detections at the current posture
    (:func:`_residuals`): the markers' exact world Jacobian, through the projections in image
    mode. Stops after
    ``max_iter`` steps, or when a step moves less than 1e-6 (degrees, model
    units) or gains less than 1e-10 of the cost at the final radius. Returns the refined
    posture.
    """
    M, D = kin.marker_joint.shape[0], q0.shape[0]
    G, C = (M, 3) if targets.shape[0] > 0 else (views.kind.shape[0] * M, 2)
    lower, upper = bounds.lower, bounds.upper
    q, trial = q0.copy(), q0.copy()
    work = workspace(kin, views, D, image.det.shape[0])
    res, res2 = np.empty((G, C)), np.empty((G, C))
    V = views.kind.shape[0]
    chosen, tried = _assignment(G, V, M), _assignment(G, V, M)  # at q, and at the step tried
    valid = chosen.valid
    jac = np.empty((G, C, D))
    n = M if targets.shape[0] == 0 else 0  # image mode's scratch
    wj, dp, view_jac = np.empty((n, 3, D)), np.empty((V, n, 2, 3)), np.empty((n, 2, D))
    A, H, L = np.empty((D, D)), np.empty((D, D)), np.empty((D, D))
    g, delta = np.empty(D), np.empty(D)
    moves = np.empty(D, dtype=np.int64)
    _residuals(q, kin, views, image, targets, work, res, chosen)
    c = huber_c
    cost = _huber_cost(res, valid, c)
    lam = 1e-3
    step, gain = np.inf, np.inf
    for _ in range(max_iter):
        _jacobian(kin, views, targets, work, chosen, wj, dp, view_jac, jac)
        A[:] = 0.0
        g[:] = 0.0
        for k in range(G):
            if not valid[k]:
                continue
            e = _norm(res, k)
            w = 1.0 if e <= c else c / e
            n = 0  # the DOFs that move group k: a leg's marker, a few of a whole animal's
            for i in range(D):
                if jac[k, 0, i] != 0.0 or jac[k, 1, i] != 0.0 or jac[k, C - 1, i] != 0.0:
                    moves[n] = i
                    n += 1
            for a in range(C):
                for s in range(n):
                    i = moves[s]
                    g[i] -= w * jac[k, a, i] * res[k, a]
                    for t in range(s + 1):
                        A[i, moves[t]] += w * jac[k, a, i] * jac[k, a, moves[t]]
        for i in range(D):
            for j in range(i):
                A[j, i] = A[i, j]
        improved = False
        while lam < 1e8:
            _copy(H.ravel(), A.ravel())
            for i in range(D):
                H[i, i] += lam * (A[i, i] + 1e-9)
            _cholesky_solve(H, g, L, delta)
            for i in range(D):
                trial[i] = min(max(q[i] + delta[i], lower[i]), upper[i])
            moved = np.max(np.abs(trial - q))
            if moved < 1e-6:
                break  # converged: more damping only shortens the step (saves ~15 trials)
            _residuals(trial, kin, views, image, targets, work, res2, tried)
            new_cost = _huber_cost(res2, tried.valid, c)
            if new_cost < cost:
                step = moved
                gain = cost - new_cost
                _copy(q, trial)
                _copy(res.ravel(), res2.ravel())
                _keep(chosen, tried)
                cost = new_cost
                lam = max(lam / 3.0, 1e-9)
                improved = True
                break
            lam *= 4.0
        # Converged: LM takes 4-5 steps from a degree or two away; more change nothing.
        if not improved or step < 1e-6 or gain <= 1e-10 * cost:
            if targets.shape[0] > 0 or not _tightens(res, valid, c):
                break
            c = MIN_RADIUS_PX
            # The Jacobian reads q's evaluation from ``work``, which a rejected trial may hold:
            # evaluated again (an accepted step leaves it there, and this is the only way on
            # without one).
            _residuals(q, kin, views, image, targets, work, res, chosen)
            cost = _huber_cost(res, valid, c)
            lam, step, gain = 1e-3, np.inf, np.inf
    return q


# ---- Simulated Annealing (Eq. 6) ---------------------------------------------------------------


@njit(cache=True, inline="always")
def _propose(cur, cand, step, sigma, lower, upper, hist, turns, bins_per_degree, h_min, state):
    """Eq. 6: ``cand = cur + l·v``, ``v_i = s(H_i)·r_i``, each component redrawn while implausible.

    Implausible: outside the DOF's range, or (angles) in a histogram bin below
    T_h. Up to 32 draws per component, then it stays unchanged. ``turns[i]``
    (whole turns below the range's lower end, -1 for translations) maps an angle
    of the range into [0, 720) without a floor per draw.
    """
    B = hist.shape[1]
    for i in range(cur.shape[0]):
        base, scale = cur[i], step * sigma[i]
        value = base
        for _ in range(32):
            trial = base + scale * (2.0 * next_uniform(state) - 1.0)
            ok = lower[i] <= trial <= upper[i]
            if ok and turns[i] >= 0.0:
                b = np.int64((trial - 360.0 * turns[i]) * bins_per_degree)
                b = b - B if b >= B else b
                b = B - 1 if b >= B else b
                ok = hist[i, b] >= h_min
            if ok:
                value = trial
                break
        cand[i] = value


# LM steps of a polish. A polish tests a basin (is its bottom below eps?); the attempt's
# final refinement (50 steps) reads off the bottom. LM needs 4-5 steps from a degree or two
# away; polishes of SA's current posture and of drawn postures start farther and ran all of
# 20 steps for little: 10 gives the same SA iterations and accuracy, faster
# (docs/ENGINE_NOTES.md).
_POLISH_STEPS = 10


@njit(cache=True, nogil=True)
def _polish(q, e_q, bounds, kin, views, image, huber_c, out) -> float:
    """Refine ``q`` (:data:`_POLISH_STEPS` LM steps) into ``out`` if that lowers its error on
    ``image``; return the error of ``out``.

    With ``image.lost_px`` (the objective lets each view lose a marker), the refinement leaves
    out the markers :func:`_lost_markers` finds at ``q``: otherwise it pulls a lost
    marker onto the nearest other blob, the very pull the objective is there to stop.
    """
    unseen = image.unseen
    if image.lost_px > 0.0:
        mask, lost = _lost_markers(q, kin, views, image, image.lost_px, np.bool_(False))
        if lost:
            unseen = mask
    polished = refine(q, bounds, kin, views, _with(image, image.fuse_px, image.lost_px, unseen),
                      huber_c, np.int64(_POLISH_STEPS), _no_targets())
    e_pol = posture_error(polished, kin, views, image)
    if e_pol < e_q:
        _copy(out, polished)
        return e_pol
    _copy(out, q)
    return e_q


@njit(cache=True, nogil=True)
def anneal(q0, bounds, kin, views, image, sa, state):
    """Simulated Annealing of the objective on ``image`` over the DOFs (paper Eq. 6 and §2.3).

    ``q0`` (D,): the start, within ``bounds`` (:class:`Bounds`); ``sa``: :class:`SAParams`
    (``refine_result`` and ``restarts`` not read); ``state``: the xoshiro256** state (4,)
    uint64, advanced. Proposals by :func:`_propose`; Metropolis acceptance at temperature
    ``tau``; ``tau *= c_tau`` every ``n_tau`` and ``l *= c_l`` every ``n_l`` iterations;
    stops after ``n_end`` iterations or when the best error is below ``eps``.
    ``hist`` (D,B) holds each DOF's probabilities (NaN row for translations).

    ``polish_every`` > 0: every that many iterations the best posture is refined
    (:func:`refine`) and, while it is not below ``eps``, so is the current one
    (keeping whichever becomes the best). The ``E < eps`` stop is then tested on
    polished postures: SA still chooses the basins, refinement reads off their
    bottom instead of waiting for the step length to shrink, and a basin SA is
    passing through counts even when SA has not sampled near its bottom.
    0 is the paper's plain SA. While the best stays at or above ``eps`` after a round's
    polishes, ``draws`` postures are drawn from the histograms (:func:`draw_posture`) and
    the one of lowest error is polished too: where SA has not found the basin yet, the
    histograms propose where this animal's joints usually are (screening costs one error
    evaluation a draw; polishing every draw cost more than it saved).

    ``patience`` > 0 (with polishing): SA also stops after that many polish
    rounds in a row without lowering the best error by 1 % (the
    ``niter_success`` of scipy's basin-hopping). An image whose minimum stays
    above ``eps`` (a lost marker; any real model mismatch) otherwise runs all
    ``n_end`` iterations for nothing.

    Returns (best posture, best error, iterations run).
    """
    lower, upper = bounds.lower, bounds.upper
    sigma, hist, h_min, n_end, n_l, n_tau = sa.sigma, sa.hist, sa.h_min, sa.n_end, sa.n_l, sa.n_tau
    c_l, c_tau, eps, polish_every, patience, draws = (sa.c_l, sa.c_tau, sa.eps, sa.polish_every,
                                                      sa.patience, sa.draws)
    det, start, offset, penalty = image.det, image.start, image.offset, image.penalty
    fuse_px, lost_px, unseen = image.fuse_px, image.lost_px, image.unseen
    D = q0.shape[0]
    bins_per_degree = hist.shape[1] / 360.0
    turns = np.empty(D)
    for i in range(D):
        turns[i] = -1.0 if np.isnan(hist[i, 0]) else np.floor(lower[i] / 360.0)
    work = workspace(kin, views, D, det.shape[0])
    raw, fused, index, dist, claims = work.raw, work.fused, work.index, work.dist, work.claims
    cur, cand, best, seed_q = q0.copy(), q0.copy(), q0.copy(), q0.copy()
    e_cur = e_best = np.inf  # the first pass evaluates q0 itself and always accepts it
    tau, step = sa.tau0, sa.l0
    it = -1
    e_mark, stale = np.inf, 0
    while it < n_end and e_best >= eps:
        it += 1
        limit = np.inf
        if it > 0:
            _propose(cur, cand, step, sigma, lower, upper, hist, turns, bins_per_degree, h_min, state)
            # Metropolis: accept iff e_new <= e_cur - tau*ln(u); drawing u first lets
            # the error stop summing as soon as the proposal is certainly rejected.
            u = next_uniform(state)
            limit = e_cur - tau * math.log(u) if u > 0.0 else np.inf
        project_posture(cand, kin, views, offset, fuse_px, work)
        e_new = blob_error(raw, fused, det, start, penalty, fuse_px, lost_px, limit, index, dist,
                           claims, unseen)
        if e_new <= limit:
            _copy(cur, cand)
            e_cur = e_new
            if e_cur < e_best:
                _copy(best, cur)
                e_best = e_cur
        if it == 0:
            continue
        if it % n_tau == 0:
            tau *= c_tau
        if it % n_l == 0:
            step *= c_l
        if polish_every > 0 and it % polish_every == 0:
            e_best = _polish(best, e_best, bounds, kin, views, image, sa.huber_c, best)
            if e_best >= eps:
                e_hop = _polish(cur, np.inf, bounds, kin, views, image, sa.huber_c, cand)
                if e_hop < e_best:
                    _copy(best, cand)
                    e_best = e_hop
            if e_best >= eps and draws > 0:
                e_seed = np.inf
                for _ in range(draws):
                    draw_posture(lower, upper, hist, state, cand)
                    e_new = _evaluate(cand, kin, views, image, e_seed, work)
                    if e_new < e_seed:
                        e_seed = e_new
                        _copy(seed_q, cand)
                e_draw = _polish(seed_q, e_seed, bounds, kin, views, image, sa.huber_c, cand)
                if e_draw < e_best:
                    _copy(best, cand)
                    e_best = e_draw
            if e_best < e_mark * 0.99:
                e_mark, stale = e_best, 0
            else:
                stale += 1
                if 0 < patience <= stale:
                    break
    return best, e_best, it


# ---- one attempt on one image ---------------------------------------------------------------


@njit(cache=True, nogil=True)
def _splitmix64(x):
    """SplitMix64 step: (next state, output), the seeding generator xoshiro's authors recommend."""
    x = x + np.uint64(0x9E3779B97F4A7C15)
    z = x
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x, z ^ (z >> np.uint64(31))


@njit(cache=True, nogil=True)
def stream_state(seed, sample, attempt):
    """xoshiro256** state (4 uint64) of one attempt on one image, from three uint64 keys.

    Each key is folded through SplitMix64 in turn, then four outputs fill the
    state (never all zero: SplitMix64 is a bijection of a non-constant sequence).
    """
    x, h = _splitmix64(seed)
    x, h = _splitmix64(h ^ sample)
    x, h = _splitmix64(h ^ attempt)
    state = np.empty(4, dtype=np.uint64)
    for i in range(4):
        x, state[i] = _splitmix64(x)
    return state


@njit(cache=True, nogil=True)
def draw_posture(lower, upper, hist, state, out) -> None:
    """A random posture into ``out``: angles drawn from the histograms, translations uniform.

    An angle's bin is drawn by its probability, the angle uniformly within the bin,
    then expressed in the DOF's range; rows of NaN (translations) or of zeros are
    drawn uniformly in the range. Every value ends inside its range.
    """
    bins = hist.shape[1]
    width = 360.0 / bins
    for i in range(out.shape[0]):
        total = 0.0 if np.isnan(hist[i, 0]) else np.sum(hist[i])
        if total <= 0.0:
            out[i] = lower[i] + (upper[i] - lower[i]) * next_uniform(state)
            continue
        target, acc, b = next_uniform(state) * total, 0.0, bins - 1
        for k in range(bins):
            acc += hist[i, k]
            if acc > target:
                b = k
                break
        angle = (b + next_uniform(state)) * width
        value = lower[i] + (angle - lower[i]) % 360.0
        out[i] = min(max(value, lower[i]), upper[i])


@njit(cache=True, nogil=True)
def _lost_markers(q, kin, views, image, beyond, every):
    """In every view of ``image``, the worst-matched marker if it is farther than ``beyond`` px
    from its detection (what losing it costs), or with ``every`` each marker that far:
    (V, M) mask, and whether any was found. A marker outside its view's region counts
    ``image.penalty`` far (:func:`charged_unseen`): the objective charges it that already.

    Kernels pass ``every`` as ``np.bool_(...)``, a value: a literal ``True`` or ``False`` would
    make numba compile this kernel once per literal, besides the ``bool`` of Python's calls.
    """
    det, start, penalty, fuse_px = image.det, image.start, image.penalty, image.fuse_px
    V, M = views.kind.shape[0], kin.marker_joint.shape[0]
    work = workspace(kin, views, q.shape[0], det.shape[0])
    _project(q, kin, views, image.offset, fuse_px, work)
    raw, fused, index, dist, claims = work.raw, work.fused, work.index, work.dist, work.claims
    unseen = np.zeros((V, M), dtype=np.bool_)
    seen = charged_unseen(_no_unseen(), views.bounds, raw, work.hidden, fuse_px)
    lost = False
    for v in range(V):
        a, b = start[v], start[v + 1]
        if a == b:
            continue
        merged = fuse_px > 0.0 and _view_reading(raw, fused, v, det, a, b, penalty, fuse_px, 0.0,
                                                  seen, index, dist, claims)[1] >= 0.0
        _match_view(fused if merged else raw, v, det, a, b, index, dist, seen, penalty)
        worst = np.argmax(dist)
        if dist[worst] > beyond:
            lost = True
            for m in range(M):
                unseen[v, m] = m == worst or (every and dist[m] > beyond)
    return unseen, lost


@njit(cache=True, nogil=True)
def _refit_unseen(q, objective, bounds, kin, views, image, huber_c):
    """Refit ``q`` (in place) without the markers that look lost; return the objective kept.

    A marker the camera lost (occluded) is charged its distance to some other
    blob, and the fit leans towards it. After an attempt, in every view every
    marker farther than ``image.penalty`` from its detection (:func:`_lost_markers`) is
    taken as not seen: the posture is refined without those markers, and kept if its
    objective, with them charged ``penalty`` (and ``image.lost_px``, ``image.unseen`` not
    read), is lower than ``objective``. Every one, not only each view's worst: a limb
    can hide several markers from one camera, and each one left in pulls the refit
    onto another blob (docs/BENCH_SUBJECTS.md, occlusion).
    Images whose markers are all within ``penalty`` are left as they are.
    """
    unseen, lost = _lost_markers(q, kin, views, image, image.penalty, np.bool_(True))
    if not lost:
        return objective
    masked = _with(image, image.fuse_px, 0.0, unseen)
    refit = refine(q, bounds, kin, views, masked, huber_c, np.int64(50), _no_targets())
    e_refit = posture_error(refit, kin, views, masked)
    if e_refit < objective:
        _copy(q, refit)
        return e_refit
    return objective


@njit(cache=True, nogil=True)
def _unbounded(views):
    """``views`` without their regions (``views.bounds`` infinite): every marker may be seen."""
    edges = np.empty((views.kind.shape[0], 4))
    for v in range(edges.shape[0]):
        edges[v, 0], edges[v, 1], edges[v, 2], edges[v, 3] = -np.inf, -np.inf, np.inf, np.inf
    return RigArrays(views.kind, views.P, views.K, views.dist, edges)


@njit(cache=True, nogil=True)
def fit_attempt(start_q, draw_start, bounds, kin, views, image, sa, state, runs):
    """One attempt on one image: SA, restarted while above ``eps``, each result refined.

    ``image``: :class:`Image` (``lost_px`` not read: each run sets it); ``sa``:
    :class:`SAParams`; ``state``: the xoshiro256** state (4,) uint64, advanced; ``runs``
    (R, d): each run's final posture is written to its next row, the first R runs (R may
    be 0), so that a caller can judge the runs' minima by another measure (a tree's
    branches, ``core.treefit``).
    The first run starts from ``start_q`` (the histogram means), or from a posture
    drawn from the histograms when ``draw_start`` (re-analysis); restarts, up to
    ``restarts`` while the best objective is still >= ``eps``, from drawn postures.
    A restart that does not find a minimum 1 % lower than the best so far says
    that minimum is the image's own (detection noise, a model that does not quite
    fit keep it above ``eps``), and ends the restarts, unless the best still costs
    ``penalty`` or more, a whole lost marker's charge: there, SA is likely in a basin
    that puts a hidden marker on another blob while the true posture scores the
    penalty alone (docs/ENGINE_NOTES.md: a hidden tarsus marker). Each run's result is refit
    without the markers that look lost (:func:`_refit_unseen`). Restarts search an
    objective that lets every view lose one marker (charged ``penalty``): an
    image that stays above ``eps`` is where a marker may be occluded, and its
    distance to some other blob would otherwise lead the search astray; runs
    are compared, and the objective returned, in that objective (the same as the
    first run's wherever every marker is within ``penalty``). SA itself reads the views
    without their regions (:func:`_unbounded`) unless ``search_edges``: a marker out of its
    view's frame is charged its nearest detection, as in the paper's Eq. 5, so that SA is
    never drawn out of the frames, where a whole limb would cost the penalty a marker and
    no blob would steer it back; the refinement and the comparisons after it charge such a
    marker as unseen (:func:`charged_unseen`). With ``refine_result``,
    each run's posture is refined
    and kept if that does not raise the objective. Returns (posture, plain Eq. 5
    error, objective, SA iterations, rows of ``runs`` written); the objective is Eq. 5
    with fusion below ``fuse_px``.
    """
    penalty, fuse_px, unseen = image.penalty, image.fuse_px, image.unseen
    charged = _with(image, fuse_px, penalty, unseen)  # every view may lose a marker
    searching = views if sa.search_edges else _unbounded(views)
    q0, best = start_q.copy(), start_q.copy()
    objective, iterations, written = np.inf, 0, 0
    for run in range(sa.restarts + 1):
        if run > 0 and objective < sa.eps:
            break
        if run > 0 or draw_start:
            draw_posture(bounds.lower, bounds.upper, sa.hist, state, q0)
        searched = charged if run > 0 else _with(image, fuse_px, 0.0, unseen)
        q, value, its = anneal(q0, bounds, kin, searching, searched, sa, state)
        iterations += its
        if sa.refine_result:
            polished = refine(q, bounds, kin, views, searched, sa.huber_c, np.int64(50), _no_targets())
            e_pol = posture_error(polished, kin, views, searched)
            if e_pol <= value:
                q = polished
        value = posture_error(q, kin, views, charged)
        if sa.refine_result:
            value = _refit_unseen(q, value, bounds, kin, views, image, sa.huber_c)
        if written < runs.shape[0]:
            _copy(runs[written], q)
            written += 1
        if run > 0 and value >= 0.99 * objective and objective < penalty:
            break
        if value < objective:
            _copy(best, q)
            objective = value
    error = plain_error(best, kin, views, image)
    return best, error, objective, iterations, written


# ---- depth-flip alternatives (kinematic jumps) ------------------------------------------------


@njit(cache=True, nogil=True)
def _reflect(points, rows, origin, normal) -> None:
    """Reflect ``points[k]`` for every ``rows[k]`` through the plane (origin, unit normal)."""
    for k in range(points.shape[0]):
        if rows[k]:
            d = ((points[k, 0] - origin[0]) * normal[0] + (points[k, 1] - origin[1]) * normal[1]
                 + (points[k, 2] - origin[2]) * normal[2])
            for a in range(3):
                points[k, a] -= 2.0 * d * normal[a]


@njit(cache=True, nogil=True)
def flip_alternatives(q, objective, tolerance, bounds, kin, views, image, huber_c, geometry,
                      max_refined, out_q, out_objective):
    """Other postures that image (almost) like ``q``: one view's depth flips (kinematic jumps).

    A view does not see depth along its viewing direction: reflecting the part
    of the model below a joint through the plane that contains the joint and is
    normal to that direction leaves the view's image unchanged (exactly for an
    orthographic view, nearly for a perspective one). For every view and every
    subset ``masks`` of ``flip_joints`` (bit f: flip the subtree of joint f, root
    side first), the reflected marker configuration is scored in all views; if
    it is within ``tolerance`` of ``objective``, inverse kinematics finds the
    posture nearest to it within the DOF ranges, and image refinement polishes
    it. Distinct postures (some DOF more than 1 apart) scoring within
    ``tolerance`` of ``objective`` on ``image`` (:class:`Image`) are written to
    ``out_q``/``out_objective``.

    ``geometry``: ``core.ambiguity.FlipGeometry``, whose ``depth`` (V,3) is the viewing
    direction, or the camera centre where ``perspective``; ``subtree_joints`` (F,J) and
    ``subtree_markers`` (F,M): what lies below each flip joint. At most ``max_refined`` flips
    that pass the screen are refined (each refinement costs D evaluations a step). Returns
    how many alternatives were written.
    """
    J, M, D = kin.parent.shape[0], kin.marker_joint.shape[0], q.shape[0]
    V = views.kind.shape[0]
    flip_joints, subtree_joints, subtree_markers = (geometry.flip_joints, geometry.subtree_joints,
                                                    geometry.subtree_markers)
    depth, perspective, masks = geometry.depth, geometry.perspective, geometry.masks
    work = workspace(kin, views, D, image.det.shape[0])
    fr, sc, raw, fused = work.frames, work.sincos, work.raw, work.fused
    joint_frames(q, kin, fr, sc)
    world = np.empty((M, 3))
    world_markers(fr, kin, world)
    joints = np.empty((J, 3))
    for k in range(J):
        for a in range(3):
            joints[k, a] = fr[FRAME * k + 9 + a]
    targets, moved = np.empty((M, 3)), np.empty((J, 3))
    normal = np.empty(3)
    found = refined = np.int64(0)
    for v in range(V):
        for mask in masks:
            _copy(targets.ravel(), world.ravel())
            _copy(moved.ravel(), joints.ravel())
            for f in range(flip_joints.shape[0]):
                if (mask >> f) & 1 == 0:
                    continue
                origin = moved[flip_joints[f]].copy()
                for a in range(3):
                    normal[a] = origin[a] - depth[v, a] if perspective[v] else depth[v, a]
                length = math.sqrt(normal[0] ** 2 + normal[1] ** 2 + normal[2] ** 2)
                if length < 1e-12:
                    continue
                normal /= length
                _reflect(targets, subtree_markers[f], origin, normal)
                _reflect(moved, subtree_joints[f], origin, normal)
            project_markers(targets, views, image.offset, raw)
            if image.fuse_px > 0.0:
                fuse_projections(raw, image.fuse_px, fused)
            limit = objective + tolerance
            if _objective(views, image, limit, work) > limit:
                continue
            if refined == max_refined:
                return found
            refined += 1
            reached = refine(q, bounds, kin, views, image, 1e9, np.int64(30), targets)
            cand = refine(reached, bounds, kin, views, image, huber_c, np.int64(50), _no_targets())
            e_cand = posture_error(cand, kin, views, image)
            if e_cand > objective + tolerance or not _distinct(cand, q, out_q, found):
                continue
            _copy(out_q[found], cand)
            out_objective[found] = e_cand
            found += 1
            if found == out_q.shape[0]:
                return found
    return found


@njit(cache=True, nogil=True)
def _distinct(cand, q, kept, n) -> bool:
    """True if some DOF of ``cand`` is more than 1 (degree, model unit) from ``q`` and each kept."""
    if np.max(np.abs(cand - q)) <= 1.0:
        return False
    for k in range(n):  # noqa: SIM110 (numba compiles no generator for all())
        if np.max(np.abs(cand - kept[k])) <= 1.0:
            return False
    return True
