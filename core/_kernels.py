"""Compiled kernels: forward kinematics, projection, Eq. 5, Simulated Annealing, refinement.

Everything here trusts its input: the public functions in ``model``, ``rig``,
``error``, ``anneal`` and ``refine`` validate once and call these on contiguous
float64 / int64 arrays. Angles inside the kernels are degrees unless a name says
``rad``. Views are stored as 3×4 matrices (an affine view has the third row
``[0, 0, 0, 1]``, so ``u = h0 / h2`` is exact for it too); pinhole views carry
``[R | t]`` there plus ``K`` and OpenCV's 8 distortion coefficients.

The SA kernel draws from its own xoshiro256** generator, seeded from the
caller's ``numpy.random.Generator``: a draw costs ~1 ns instead of ~7 ns for a
Generator called from numba, and the SA inner loop makes six per iteration.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

DEG = math.pi / 180.0
PINHOLE = 1
BEHIND_CAMERA = 1.0e9  # pixel coordinate given to points behind a pinhole camera

# ---- rotations and forward kinematics -------------------------------------------------


@njit(cache=True)
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


@njit(cache=True)
def sincos_deg(angle):
    """(sin, cos) of an angle in degrees, to a few ulp, in ~6 ns instead of ~16 ns for libm.

    Exact reduction by quarter turns (degrees make it exact), then fdlibm's
    polynomials on |x| <= 45°. FK needs one per free axis per SA iteration.
    """
    n = math.floor(angle * (1.0 / 90.0) + 0.5)
    x = (angle - 90.0 * n) * DEG
    z = x * x
    s = x + x * z * (_S1 + z * (_S2 + z * (_S3 + z * (_S4 + z * (_S5 + z * _S6)))))
    c = 1.0 - 0.5 * z + z * z * (_C1 + z * (_C2 + z * (_C3 + z * (_C4 + z * (_C5 + z * _C6)))))
    quadrant = int(n) & 3
    if quadrant == 0:
        return s, c
    if quadrant == 1:
        return c, -s
    if quadrant == 2:
        return -s, -c
    return -c, s


@njit(cache=True)
def _mix(angle_deg, a0, a1, a2, b0, b1, b2):
    """Columns (a, b) of M·R for an elementary rotation R mixing them: (c·a + s·b, c·b − s·a).

    Rz mixes columns (0, 1), Rx (1, 2) and Ry (2, 0); 12 flops instead of a 3×3 product.
    """
    s, c = sincos_deg(angle_deg)
    return (c * a0 + s * b0, c * a1 + s * b1, c * a2 + s * b2,
            c * b0 - s * a0, c * b1 - s * a1, c * b2 - s * a2)


@njit(cache=True)
def forward_kinematics(q, kin, rot, pos) -> None:
    """World rotation ``rot`` (J,3,3) and origin ``pos`` (J,3) of every joint for posture ``q``.

    W_j = W_parent · T(offset + t) · R(rest) · Ry · Rx · Rz, locked axes and
    identity rest orientations skipped. Each joint's frame lives in scalars
    (columns c0, c1, c2) and is stored once: the compiler cannot prove that
    ``rot[k]`` and ``rot[parent]`` do not overlap, and would reload after every store.
    """
    parent, offset, rest, rest_identity = kin[0], kin[1], kin[2], kin[3]
    rot_dof, trans_dof = kin[4], kin[5]
    for k in range(parent.shape[0]):
        t0, t1, t2 = offset[k, 0], offset[k, 1], offset[k, 2]
        if trans_dof[k, 0] >= 0:
            t0 += q[trans_dof[k, 0]]
        if trans_dof[k, 1] >= 0:
            t1 += q[trans_dof[k, 1]]
        if trans_dof[k, 2] >= 0:
            t2 += q[trans_dof[k, 2]]
        p = parent[k]
        if p < 0:
            x, y, z = t0, t1, t2
            b00, b01, b02 = 1.0, 0.0, 0.0
            b10, b11, b12 = 0.0, 1.0, 0.0
            b20, b21, b22 = 0.0, 0.0, 1.0
        else:
            b00, b01, b02 = rot[p, 0, 0], rot[p, 0, 1], rot[p, 0, 2]
            b10, b11, b12 = rot[p, 1, 0], rot[p, 1, 1], rot[p, 1, 2]
            b20, b21, b22 = rot[p, 2, 0], rot[p, 2, 1], rot[p, 2, 2]
            x = pos[p, 0] + b00 * t0 + b01 * t1 + b02 * t2
            y = pos[p, 1] + b10 * t0 + b11 * t1 + b12 * t2
            z = pos[p, 2] + b20 * t0 + b21 * t1 + b22 * t2
        if rest_identity[k]:
            a00, a01, a02, a10, a11, a12, a20, a21, a22 = b00, b01, b02, b10, b11, b12, b20, b21, b22
        else:
            R = rest[k]
            a00 = b00 * R[0, 0] + b01 * R[1, 0] + b02 * R[2, 0]
            a01 = b00 * R[0, 1] + b01 * R[1, 1] + b02 * R[2, 1]
            a02 = b00 * R[0, 2] + b01 * R[1, 2] + b02 * R[2, 2]
            a10 = b10 * R[0, 0] + b11 * R[1, 0] + b12 * R[2, 0]
            a11 = b10 * R[0, 1] + b11 * R[1, 1] + b12 * R[2, 1]
            a12 = b10 * R[0, 2] + b11 * R[1, 2] + b12 * R[2, 2]
            a20 = b20 * R[0, 0] + b21 * R[1, 0] + b22 * R[2, 0]
            a21 = b20 * R[0, 1] + b21 * R[1, 1] + b22 * R[2, 1]
            a22 = b20 * R[0, 2] + b21 * R[1, 2] + b22 * R[2, 2]
        if rot_dof[k, 0] >= 0:  # Ry mixes columns 2 and 0
            a02, a12, a22, a00, a10, a20 = _mix(q[rot_dof[k, 0]], a02, a12, a22, a00, a10, a20)
        if rot_dof[k, 1] >= 0:  # Rx mixes columns 1 and 2
            a01, a11, a21, a02, a12, a22 = _mix(q[rot_dof[k, 1]], a01, a11, a21, a02, a12, a22)
        if rot_dof[k, 2] >= 0:  # Rz mixes columns 0 and 1
            a00, a10, a20, a01, a11, a21 = _mix(q[rot_dof[k, 2]], a00, a10, a20, a01, a11, a21)
        rot[k, 0, 0], rot[k, 0, 1], rot[k, 0, 2] = a00, a01, a02
        rot[k, 1, 0], rot[k, 1, 1], rot[k, 1, 2] = a10, a11, a12
        rot[k, 2, 0], rot[k, 2, 1], rot[k, 2, 2] = a20, a21, a22
        pos[k, 0], pos[k, 1], pos[k, 2] = x, y, z


@njit(cache=True)
def markers_from_joints(rot, pos, kin, out) -> None:
    """World position (M,3) of every marker from joint frames."""
    marker_joint, marker_pos = kin[6], kin[7]
    for m in range(marker_joint.shape[0]):
        j = marker_joint[m]
        for r in range(3):
            out[m, r] = (
                pos[j, r]
                + rot[j, r, 0] * marker_pos[m, 0]
                + rot[j, r, 1] * marker_pos[m, 1]
                + rot[j, r, 2] * marker_pos[m, 2]
            )


@njit(cache=True)
def marker_positions_many(Q, kin):
    """World marker positions (T,M,3) for postures Q (T,D)."""
    J, M = kin[0].shape[0], kin[6].shape[0]
    out = np.empty((Q.shape[0], M, 3))
    rot, pos = np.empty((J, 3, 3)), np.empty((J, 3))
    for t in range(Q.shape[0]):
        forward_kinematics(Q[t], kin, rot, pos)
        markers_from_joints(rot, pos, kin, out[t])
    return out


# ---- projection ------------------------------------------------------------------------


@njit(cache=True)
def _distort(K, dist, v, x, y):
    """OpenCV's pinhole model: normalised (x, y) → distorted → pixels through K (no skew)."""
    r2 = x * x + y * y
    radial = (1.0 + r2 * (dist[v, 0] + r2 * (dist[v, 1] + r2 * dist[v, 4]))) / (
        1.0 + r2 * (dist[v, 5] + r2 * (dist[v, 6] + r2 * dist[v, 7]))
    )
    xd = x * radial + 2.0 * dist[v, 2] * x * y + dist[v, 3] * (r2 + 2.0 * x * x)
    yd = y * radial + dist[v, 2] * (r2 + 2.0 * y * y) + 2.0 * dist[v, 3] * x * y
    return K[v, 0, 0] * xd + K[v, 0, 2], K[v, 1, 1] * yd + K[v, 1, 2]


@njit(cache=True)
def project_markers(world, kind, P, K, dist, offset, out) -> None:
    """Pixel coordinates (V,M,2) of world markers (M,3), plus each view's 2D offset (V,2).

    Points behind a pinhole camera (or at infinity for a DLT matrix) go to
    ``BEHIND_CAMERA`` pixels: far from every detection, never NaN.
    """
    for v in range(kind.shape[0]):
        for m in range(world.shape[0]):
            X0, X1, X2 = world[m, 0], world[m, 1], world[m, 2]
            h0 = P[v, 0, 0] * X0 + P[v, 0, 1] * X1 + P[v, 0, 2] * X2 + P[v, 0, 3]
            h1 = P[v, 1, 0] * X0 + P[v, 1, 1] * X1 + P[v, 1, 2] * X2 + P[v, 1, 3]
            h2 = P[v, 2, 0] * X0 + P[v, 2, 1] * X1 + P[v, 2, 2] * X2 + P[v, 2, 3]
            if kind[v] == PINHOLE:
                if h2 <= 1e-12:
                    u, w = BEHIND_CAMERA, BEHIND_CAMERA
                else:
                    u, w = _distort(K, dist, v, h0 / h2, h1 / h2)
            elif abs(h2) < 1e-300:
                u, w = BEHIND_CAMERA, BEHIND_CAMERA
            else:
                u, w = h0 / h2, h1 / h2
            out[v, m, 0] = u + offset[v, 0]
            out[v, m, 1] = w + offset[v, 1]


@njit(cache=True)
def project_many(world, kind, P, K, dist):
    """Pixel coordinates (T,V,M,2) of world markers (T,M,3), no offsets."""
    V = kind.shape[0]
    out = np.empty((world.shape[0], V, world.shape[1], 2))
    zero = np.zeros((V, 2))
    for t in range(world.shape[0]):
        project_markers(world[t], kind, P, K, dist, zero, out[t])
    return out


@njit(cache=True)
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
            su, sv, n = 0.0, 0.0, 0
            for k in range(raw.shape[1]):
                du, dv = raw[v, k, 0] - raw[v, m, 0], raw[v, k, 1] - raw[v, m, 1]
                if du * du + dv * dv < f2:
                    su += raw[v, k, 0]
                    sv += raw[v, k, 1]
                    n += 1
            out[v, m, 0], out[v, m, 1] = su / n, sv / n


@njit(cache=True)
def imaged_markers(q, kin, views, offset, fuse_px, work):
    """Pixel positions (V,M,2) at which the camera shows the markers of posture ``q``.

    ``work`` = (rot, pos, world, raw, fused) scratch arrays; returns ``raw`` or
    ``fused`` (``fuse_px <= 0``: no fusion, plain projections as in Eq. 5).
    """
    rot, pos, world, raw, fused = work
    kind, P, K, dist = views
    forward_kinematics(q, kin, rot, pos)
    markers_from_joints(rot, pos, kin, world)
    project_markers(world, kind, P, K, dist, offset, raw)
    if fuse_px <= 0.0:
        return raw
    fuse_projections(raw, fuse_px, fused)
    return fused


@njit(cache=True)
def workspace(kin, views):
    """Scratch arrays for :func:`imaged_markers`."""
    J, M, V = kin[0].shape[0], kin[6].shape[0], views[0].shape[0]
    return (np.empty((J, 3, 3)), np.empty((J, 3)), np.empty((M, 3)), np.empty((V, M, 2)),
            np.empty((V, M, 2)))


# ---- Eq. 5 -------------------------------------------------------------------------------


@njit(cache=True)
def eq5(proj, det, start, penalty, limit):
    """Eq. 5: sum over views and markers of the distance to the nearest detection.

    proj (V,M,2) pixels; det (N,2) detections of all views, view v in
    ``det[start[v]:start[v+1]]``. A view without detections adds ``penalty`` per
    marker. Stops summing (and returns the partial sum) once it exceeds ``limit``:
    the SA only needs to know that a proposal is rejected.
    """
    total = 0.0
    for v in range(proj.shape[0]):
        a, b = start[v], start[v + 1]
        if a == b:
            total += penalty * proj.shape[1]
            continue
        for m in range(proj.shape[1]):
            pu, pv = proj[v, m, 0], proj[v, m, 1]
            best = np.inf
            for c in range(a, b):
                du, dv = pu - det[c, 0], pv - det[c, 1]
                d2 = du * du + dv * dv
                if d2 < best:
                    best = d2
            total += math.sqrt(best)
        if total > limit:
            return total
    return total


@njit(cache=True)
def posture_error(q, kin, views, offset, det, start, penalty, fuse_px):
    """Eq. 5 for one posture: FK, projection (fused below ``fuse_px``), nearest detections."""
    proj = imaged_markers(q, kin, views, offset, fuse_px, workspace(kin, views))
    return eq5(proj, det, start, penalty, np.inf)


# ---- random numbers -------------------------------------------------------------------------


@njit(cache=True)
def _rotl(x, k):
    return (x << np.uint64(k)) | (x >> np.uint64(64 - k))


@njit(cache=True)
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


@njit(cache=True)
def _residuals(q, kin, views, offset, det, start, fuse_px, work, res, valid):
    """Residual (V,M,2) of each imaged marker to its nearest detection; valid (V,) views."""
    proj = imaged_markers(q, kin, views, offset, fuse_px, work)
    V, M = res.shape[0], res.shape[1]
    for v in range(V):
        a, b = start[v], start[v + 1]
        valid[v] = b > a
        for m in range(M):
            best, bu, bv = np.inf, 0.0, 0.0
            for c in range(a, b):
                du, dv = proj[v, m, 0] - det[c, 0], proj[v, m, 1] - det[c, 1]
                d2 = du * du + dv * dv
                if d2 < best:
                    best, bu, bv = d2, du, dv
            res[v, m, 0], res[v, m, 1] = bu, bv


@njit(cache=True)
def _huber_cost(res, valid, c):
    total = 0.0
    for v in range(res.shape[0]):
        if not valid[v]:
            continue
        for m in range(res.shape[1]):
            e = math.sqrt(res[v, m, 0] ** 2 + res[v, m, 1] ** 2)
            total += 0.5 * e * e if e <= c else c * (e - 0.5 * c)
    return total


@njit(cache=True)
def solve_spd(A, b):
    """x with A·x = b for a small symmetric positive-definite A, by Cholesky.

    The damped normal equations of :func:`refine` are D×D with D the number of
    DOFs; a direct solve avoids LAPACK (and SciPy, which numba needs for it).
    """
    n = b.shape[0]
    L = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1):
            acc = A[i, j]
            for k in range(j):
                acc -= L[i, k] * L[j, k]
            if i == j:
                L[i, i] = math.sqrt(max(acc, 1e-300))
            else:
                L[i, j] = acc / L[j, j]
    y = np.empty(n)
    for i in range(n):
        acc = b[i]
        for k in range(i):
            acc -= L[i, k] * y[k]
        y[i] = acc / L[i, i]
    x = np.empty(n)
    for i in range(n - 1, -1, -1):
        acc = y[i]
        for k in range(i + 1, n):
            acc -= L[k, i] * x[k]
        x[i] = acc / L[i, i]
    return x


@njit(cache=True)
def refine(q0, lower, upper, kin, views, offset, det, start, fuse_px, huber_c, max_iter, h_fd):
    """Levenberg–Marquardt on the Huber loss of nearest-detection residuals, within bounds.

    Nearest detections are re-chosen at every evaluation, so this polishes the
    basin SA found (sub-pixel) without committing to marker labels. Residuals
    below ``huber_c`` pixels are fitted by least squares (efficient for
    detection noise), larger ones by their length (robust to fused or missing
    markers, as Eq. 5 is). Jacobian by forward differences of ``h_fd`` degrees.
    Returns the refined posture.
    """
    kind = views[0]
    V, M, D = kind.shape[0], kin[6].shape[0], q0.shape[0]
    q = q0.copy()
    work = workspace(kin, views)
    res, res2 = np.empty((V, M, 2)), np.empty((V, M, 2))
    valid = np.empty(V, dtype=np.bool_)
    jac = np.empty((V, M, 2, D))
    _residuals(q, kin, views, offset, det, start, fuse_px, work, res, valid)
    cost = _huber_cost(res, valid, huber_c)
    lam = 1e-3
    step = np.inf
    trial = q.copy()
    for _ in range(max_iter):
        for i in range(D):
            trial[:] = q
            trial[i] += h_fd
            _residuals(trial, kin, views, offset, det, start, fuse_px, work, res2, valid)
            for v in range(V):
                for m in range(M):
                    jac[v, m, 0, i] = (res2[v, m, 0] - res[v, m, 0]) / h_fd
                    jac[v, m, 1, i] = (res2[v, m, 1] - res[v, m, 1]) / h_fd
        A = np.zeros((D, D))
        g = np.zeros(D)
        for v in range(V):
            if not valid[v]:
                continue
            for m in range(M):
                e = math.sqrt(res[v, m, 0] ** 2 + res[v, m, 1] ** 2)
                w = 1.0 if e <= huber_c else huber_c / e
                for a in range(2):
                    for i in range(D):
                        g[i] += w * jac[v, m, a, i] * res[v, m, a]
                        for k in range(D):
                            A[i, k] += w * jac[v, m, a, i] * jac[v, m, a, k]
        improved = False
        while lam < 1e8:
            H = A.copy()
            for i in range(D):
                H[i, i] += lam * (A[i, i] + 1e-9)
            delta = solve_spd(H, -g)
            for i in range(D):
                trial[i] = min(max(q[i] + delta[i], lower[i]), upper[i])
            _residuals(trial, kin, views, offset, det, start, fuse_px, work, res2, valid)
            new_cost = _huber_cost(res2, valid, huber_c)
            if new_cost < cost:
                step = np.max(np.abs(trial - q))
                q[:] = trial
                res[:] = res2
                cost = new_cost
                lam = max(lam / 3.0, 1e-9)
                improved = True
                break
            lam *= 4.0
        if not improved or step < 1e-7:
            break
    return q


# ---- Simulated Annealing (Eq. 6) ---------------------------------------------------------------


@njit(cache=True)
def _plausible(value, i, lower, upper, hist, bins_per_degree, h_min) -> bool:
    """Inside the DOF range and, for angles, H_i(value) >= T_h (paper §2.3)."""
    if value < lower[i] or value > upper[i]:
        return False
    if np.isnan(hist[i, 0]):
        return True  # translational DOF: no histogram
    b = int((value - 360.0 * math.floor(value * (1.0 / 360.0))) * bins_per_degree)
    if b >= hist.shape[1]:
        b = hist.shape[1] - 1
    return hist[i, b] >= h_min


@njit(cache=True)
def anneal(q0, lower, upper, sigma, hist, h_min, kin, views, offset, det, start, penalty, fuse_px,
           n_end, n_l, n_tau, tau0, l0, c_l, c_tau, eps, polish, huber_c, state):
    """Simulated Annealing of Eq. 5 over the DOFs (paper Eq. 6 and §2.3).

    Step ``q + l·v`` with ``v_i = sigma_i·r_i``, ``r_i ~ U[-1, 1]``; a component
    landing on an implausible value is drawn again (up to 32 times, then left
    unchanged). Metropolis acceptance at temperature ``tau``; ``tau *= c_tau``
    every ``n_tau`` and ``l *= c_l`` every ``n_l`` iterations; stops after
    ``n_end`` iterations or when the best error is below ``eps``.

    ``hist`` (D,B) holds each DOF's probabilities (NaN row for translations).

    With ``polish``, at every cooling step the best posture so far is refined
    (:func:`refine`) and kept if that lowers its error, so the ``E < eps`` stop
    is tested on a polished posture: SA still finds the basin, refinement only
    reads off its bottom instead of waiting for the step length to shrink.

    Returns (best posture, best error, iterations run).
    """
    D = q0.shape[0]
    bins_per_degree = hist.shape[1] / 360.0
    work = workspace(kin, views)
    cur = q0.copy()
    cand = q0.copy()
    e_cur = eq5(imaged_markers(cur, kin, views, offset, fuse_px, work), det, start, penalty, np.inf)
    best, e_best = cur.copy(), e_cur
    tau, step = tau0, l0
    it = 0
    while it < n_end and e_best >= eps:
        it += 1
        for i in range(D):
            value = cur[i]
            for _ in range(32):
                trial = cur[i] + step * sigma[i] * (2.0 * next_uniform(state) - 1.0)
                if _plausible(trial, i, lower, upper, hist, bins_per_degree, h_min):
                    value = trial
                    break
            cand[i] = value
        # Metropolis: accept iff e_new <= e_cur - tau*ln(u); drawing u first lets
        # eq5 stop summing as soon as the proposal is certainly rejected.
        u = next_uniform(state)
        limit = e_cur - tau * math.log(u) if u > 0.0 else np.inf
        proj = imaged_markers(cand, kin, views, offset, fuse_px, work)
        e_new = eq5(proj, det, start, penalty, limit)
        if e_new <= limit:
            cur[:] = cand
            e_cur = e_new
            if e_cur < e_best:
                best[:] = cur
                e_best = e_cur
        else:
            cand[:] = cur
        if it % n_tau == 0:
            tau *= c_tau
            if polish:
                polished = refine(best, lower, upper, kin, views, offset, det, start, fuse_px,
                                  huber_c, 20, 1e-5)
                e_pol = posture_error(polished, kin, views, offset, det, start, penalty, fuse_px)
                if e_pol < e_best:
                    best[:] = polished
                    e_best = e_pol
        if it % n_l == 0:
            step *= c_l
    return best, e_best, it
