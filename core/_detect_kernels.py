"""Compiled kernels of detection (``core.detect``) and of the field centroids (``core.fields``).

Apart from the fitting kernels (``core._kernels``): none of these calls them, save the
disc fit's 4×4 solve, :func:`core._kernels.solve_spd`, and its copies,
:func:`core._kernels._copy` (``core._kernels``' rule: no slice assignment). numba caches a kernel per function
and source file and checks only that file's time stamp: a change to ``solve_spd`` alone
leaves the disc fit's cached code stale until this file changes or the cache is cleared.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from core._kernels import _copy, solve_spd

# ---- marker regions and centroids (core.detect) ---------------------------------------------


@njit(cache=True, inline="always")
def _find(parent, i):
    """Root of ``i`` in a union-find forest, halving the path on the way."""
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@njit(cache=True, inline="always")
def _rank_at(binary, ranks, y, x):
    """Kept-region number of pixel (y, x), 0 for background or a dropped region."""
    return ranks[y * binary.shape[1] + x] if binary[y, x] else 0


@njit(cache=True, inline="always")
def _max_rank(binary, ranks, y, x, r):
    """Largest kept-region number in the (2r+1)² window around (y, x), 0 if none."""
    H, W = binary.shape
    best = 0
    for yy in range(max(y - r, 0), min(y + r + 1, H)):
        for xx in range(max(x - r, 0), min(x + r + 1, W)):
            k = _rank_at(binary, ranks, yy, xx)
            best = k if k > best else best
    return best


# Holds the GIL (no nogil): it runs for well under a millisecond per view, and ``index`` is a
# scratch array core.detect shares between calls of one roi size, which threads must not share.
@njit(cache=True)
def detect_regions(image, binary, pixels, min_area, max_area, index):
    """Marker centroids of one view: regions of bright pixels, then weighted centroids.

    ``binary`` (h,w) uint8 0/1 is the filtered, thresholded image, ``pixels``
    its non-zero flat indices in raster order. Regions are 8-connected
    components found by union-find over the bright pixels alone (a view holds a
    few hundred of them, so this beats labelling the whole image), numbered in
    raster order of their first pixel; those of ``min_area``..``max_area``
    pixels are kept. ``index`` (h·w,) int32 is scratch, read only where
    ``binary`` is set: the caller keeps one per image size (allocating 400 kB
    per call costs more than the whole labelling).

    Centroid of kept region k: the region grown by one pixel (pixels whose 3×3
    window's largest kept-region number is k) weighted by ``intensity -
    background``; the background is the mean of its ring (pixels with no kept
    region in their 3×3 window and k the largest in their 5×5), or the image's
    median when it has none; a region whose weights do not sum to a positive
    number gets its plain centroid. Returns the (K, 2) centroids (u, v) in pixels,
    centres at +0.5, and the (K,) areas in pixels of the kept regions: the weights'
    sum over the region's brightest pixel's weight, the area of a flat disc as bright
    that holds as much light (the pixel count where the weights do not sum to a
    positive number). A pixel count grows as the threshold goes down, and over-counts
    the disc's anti-aliased edge: ``core.synth``'s 4 px discs on a background of 20
    count 14 pixels at 100 and 15 at 'auto' (73), read as 4.22 and 4.37 px; this
    reads 3.98 at both (5 px: 4.96; 8 px: 7.92), so the marker diameter estimated from
    it, and the fusion distance set by that, do not depend on the threshold.
    """
    H, W = binary.shape
    n = pixels.shape[0]
    parent = np.empty(n, dtype=np.int64)
    for i in range(n):
        p = pixels[i]
        parent[i] = i
        index[p] = i
        y, x = p // W, p % W
        for dy, dx in ((0, -1), (-1, -1), (-1, 0), (-1, 1)):  # neighbours already visited
            yy, xx = y + dy, x + dx
            if yy >= 0 and 0 <= xx < W and binary[yy, xx]:
                a, b = _find(parent, i), _find(parent, index[yy * W + xx])
                if a != b:
                    parent[max(a, b)] = min(a, b)
    region = np.full(n, -1, dtype=np.int64)
    count = 0
    for i in range(n):
        root = _find(parent, i)
        if region[root] < 0:
            region[root] = count
            count += 1
        region[i] = region[root]
    area = np.zeros(count, dtype=np.int64)
    box = np.empty((count, 4), dtype=np.int64)  # x0, y0, x1, y1 (inclusive)
    box[:, 0], box[:, 1], box[:, 2], box[:, 3] = W, H, -1, -1
    for i in range(n):
        c, y, x = region[i], pixels[i] // W, pixels[i] % W
        area[c] += 1
        box[c, 0], box[c, 1] = min(box[c, 0], x), min(box[c, 1], y)
        box[c, 2], box[c, 3] = max(box[c, 2], x), max(box[c, 3], y)
    rank_of = np.zeros(count, dtype=np.int64)
    K = 0
    for c in range(count):
        if min_area <= area[c] <= max_area:
            K += 1
            rank_of[c] = K
    ranks = index  # reuse: flat kept-region number of every bright pixel
    for i in range(n):
        ranks[pixels[i]] = rank_of[region[i]]
    out = np.empty((K, 2))
    kept_area = np.empty(K)
    fallback = np.nan
    for c in range(count):
        k = rank_of[c]
        if k == 0:
            continue
        kept_area[k - 1] = area[c]
        y0, y1 = max(box[c, 1] - 2, 0), min(box[c, 3] + 3, H)
        x0, x1 = max(box[c, 0] - 2, 0), min(box[c, 2] + 3, W)
        ring, n_ring = 0.0, 0
        for y in range(y0, y1):
            for x in range(x0, x1):
                if _max_rank(binary, ranks, y, x, 1) == 0 and _max_rank(binary, ranks, y, x, 2) == k:
                    ring += image[y, x]
                    n_ring += 1
        if n_ring == 0 and np.isnan(fallback):
            fallback = np.median(image[::4, ::4].copy())
        background = ring / n_ring if n_ring else fallback
        total = su = sv = own = ou = ov = peak = 0.0
        for y in range(y0, y1):
            for x in range(x0, x1):
                if _max_rank(binary, ranks, y, x, 1) == k:
                    w = image[y, x] - background
                    total += w
                    su += w * (x + 0.5)
                    sv += w * (y + 0.5)
                if _rank_at(binary, ranks, y, x) == k:
                    own += 1.0
                    ou += x + 0.5
                    ov += y + 0.5
                    peak = max(peak, image[y, x] - background)
        if total > 0.0:
            out[k - 1, 0], out[k - 1, 1] = su / total, sv / total
        else:
            out[k - 1, 0], out[k - 1, 1] = ou / own, ov / own
        if total > 0.0 and peak > 0.0:
            kept_area[k - 1] = total / peak
    return out, kept_area


# ---- field centroids (de-interlacing) -------------------------------------------------------


_SUBCOLUMNS = 16  # midpoint rule across a pixel column: disc edge integrated to ~1e-3 px²
_DISC_TOLERANCE_PX = 1e-3  # a disc fit has converged when its centre moves less than this
_DISC_EVALUATIONS = 16  # model evaluations a disc fit may take (most converge in 3-5)


@njit(cache=True, nogil=True)
def _disc_model(cu, cv, r, xcols, yrows, out, jac):
    """Each window pixel's area inside the disc (centre cu, cv; radius r), row by row, and,
    when ``jac`` has rows, its derivatives by (cu, cv, r) into ``jac`` (n, 3).

    Pixel (row k, column c) is [xcols[c], +1) × [yrows[k], +1): exact along y (the
    chord's overlap with the pixel), midpoint rule over :data:`_SUBCOLUMNS` across x.
    The chords' half-heights h depend on the column alone, so they are computed once
    for all rows (a window holds 3-5 rows); pixels clear of the disc are 0.
    The derivatives come in the same pass (central differences took six more
    evaluations): a chord end inside the pixel moves with cv and with the half-height
    h = sqrt(r² - dx²), and h by its derivatives dx/h (cu) and r/h (r) averaged over
    the subcolumn, which stay bounded at the disc's edge where h → 0.
    """
    ncols = xcols.size
    derive = jac.shape[0] > 0
    half = np.empty(ncols * _SUBCOLUMNS)  # -1: the subcolumn misses the disc
    slopes = ncols * _SUBCOLUMNS if derive else 0  # h's derivatives, only when asked for
    dh_du, dh_dr = np.empty(slopes), np.empty(slopes)
    edge_h, edge_asin = np.empty(_SUBCOLUMNS + 1), np.empty(_SUBCOLUMNS + 1)
    width = 1.0 / _SUBCOLUMNS
    for c in range(ncols):
        if abs(xcols[c] + 0.5 - cu) > r + 0.5:  # the column misses the disc: no square roots
            half[c * _SUBCOLUMNS:(c + 1) * _SUBCOLUMNS] = -1.0
            continue
        for s in range(_SUBCOLUMNS):
            dx = xcols[c] + (s + 0.5) * width - cu
            half[c * _SUBCOLUMNS + s] = math.sqrt(r * r - dx * dx) if abs(dx) < r else -1.0
        if not derive:
            continue
        # the averages of dx/h and r/h over a subcolumn, from h and asin at its edges
        for s in range(_SUBCOLUMNS + 1):
            e = xcols[c] + s * width - cu
            if abs(e) < r:
                edge_h[s], edge_asin[s] = math.sqrt(r * r - e * e), math.asin(e / r)
            else:
                edge_h[s], edge_asin[s] = 0.0, math.copysign(0.5 * math.pi, e)
        for s in range(_SUBCOLUMNS):
            dh_du[c * _SUBCOLUMNS + s] = (edge_h[s] - edge_h[s + 1]) / width
            dh_dr[c * _SUBCOLUMNS + s] = r * (edge_asin[s + 1] - edge_asin[s]) / width
    for k in range(yrows.size):
        y0 = yrows[k]
        for c in range(ncols):
            i = k * ncols + c
            out[i] = 0.0
            if derive:
                jac[i, 0] = jac[i, 1] = jac[i, 2] = 0.0
            if abs(xcols[c] + 0.5 - cu) > r + 0.5 or abs(y0 + 0.5 - cv) > r + 0.5:
                continue
            total = d_u = d_v = d_r = 0.0
            for s in range(c * _SUBCOLUMNS, (c + 1) * _SUBCOLUMNS):
                h = half[s]
                if h >= 0.0:
                    top, bottom = cv + h, cv - h
                    hi = min(y0 + 1.0, top)
                    lo = max(y0, bottom)
                    if hi > lo:
                        total += hi - lo
                        if derive:  # a chord end inside the pixel moves it: top +, bottom -
                            top_in = 1.0 if top < y0 + 1.0 else 0.0
                            bottom_in = 1.0 if bottom > y0 else 0.0
                            d_v += top_in - bottom_in
                            d_u += (top_in + bottom_in) * dh_du[s]
                            d_r += (top_in + bottom_in) * dh_dr[s]
            out[i] = total / _SUBCOLUMNS
            if derive:
                jac[i, 0], jac[i, 1], jac[i, 2] = d_u / _SUBCOLUMNS, d_v / _SUBCOLUMNS, d_r / _SUBCOLUMNS


@njit(cache=True, nogil=True)
def fit_field_discs(image, centres, radii, x_off, y_off, pitch, fitted, misfit):
    """Disc-model centres of markers in a field image.

    A field holds every ``pitch``-th frame row: a marker a few pixels across covers
    two or three of its rows, and the weighted centroid of so few samples locks onto
    them. Field pixel (row k, column j) sees the frame pixel [j + x_off, … + 1) ×
    [pitch·k + y_off, … + 1); a sharp round marker of uniform brightness covers it by
    the disc's area inside it. Gauss–Newton fits centre, radius and brightness to the
    pixels around each detection (minus the mean of the window's border).

    image : (h, w) uint8 or float, one view's roi of a field.
    centres : (K, 2) frame-pixel (u, v) of its detections; radii : (K,) their starting
        radii, frame pixels.
    fitted : (K, 2) out, the disc centres; misfit : (K,) out, the fit's residual energy
        beyond the background noise's (from the border's variance) over the data's energy
        (0: a sharp disc), NaN where the fit failed or strayed more
        than 1 px or a factor 2 in radius from its start.
    """
    h, w = image.shape
    for k in range(centres.shape[0]):
        misfit[k] = np.nan
        r0 = radii[k]
        cu, cv = centres[k, 0], centres[k, 1]
        cj = math.floor(cu - x_off)
        ck = math.floor((cv - y_off) / pitch)
        reach = math.ceil(r0 + 1.5)
        j0, j1 = max(0, cj - reach), min(w, cj + reach + 1)
        rows = math.ceil(reach / pitch)
        k0, k1 = max(0, ck - rows), min(h, ck + rows + 1)
        if j1 - j0 < 3 or k1 - k0 < 3:
            continue
        n = (j1 - j0) * (k1 - k0)
        data = np.empty(n)
        xcols, yrows = np.empty(j1 - j0), np.empty(k1 - k0)
        for col in range(j0, j1):
            xcols[col - j0] = col + x_off
        for row in range(k0, k1):
            yrows[row - k0] = pitch * row + y_off
        border, border2, n_border, i = 0.0, 0.0, 0, 0
        for row in range(k0, k1):
            for col in range(j0, j1):
                data[i] = image[row, col]
                if row == k0 or row == k1 - 1 or col == j0 or col == j1 - 1:
                    border += data[i]
                    border2 += data[i] * data[i]
                    n_border += 1
                i += 1
        mean = border / n_border
        data -= mean
        noise = max(0.0, border2 / n_border - mean * mean) * (n - 4)  # residual energy of a perfect fit
        theta = np.array([cu, cv, r0])
        if not _gauss_newton_disc(theta, data, xcols, yrows):
            continue
        if abs(theta[0] - cu) < 1.0 and abs(theta[1] - cv) < 1.0 and 0.5 * r0 < theta[2] < 2.0 * r0:
            fitted[k, 0], fitted[k, 1] = theta[0], theta[1]
            misfit[k] = _relative_misfit(theta, data, xcols, yrows, noise)


@njit(cache=True, nogil=True)
def _relative_misfit(theta, data, xcols, yrows, noise):
    """Residual energy of the best-scaled disc beyond ``noise`` (the background's share),
    over the data's energy."""
    model = np.empty(data.size)
    _disc_model(theta[0], theta[1], theta[2], xcols, yrows, model, np.empty((0, 3)))
    mm, dm, dd = 0.0, 0.0, 0.0
    for i in range(data.size):
        mm += model[i] * model[i]
        dm += data[i] * model[i]
        dd += data[i] * data[i]
    if mm <= 0.0 or dd <= 0.0:
        return np.inf
    return max(0.0, dd - dm * dm / mm - noise) / dd


@njit(cache=True, inline="always")
def _step_from(kept, step, theta) -> None:
    """``theta[:] = kept + step`` for 1-D float64 arrays of one length, as a loop (no slice
    assignment: see :func:`core._kernels._copy`)."""
    for p in range(theta.shape[0]):
        theta[p] = kept[p] + step[p]


@njit(cache=True, nogil=True)
def _gauss_newton_disc(theta, data, xcols, yrows):
    """Fit ``a``·disc(theta) to ``data`` by Gauss–Newton; True if it converged.

    The model is piecewise smooth: a chord end crossing a pixel's edge is a kink, and
    full steps can cycle across one (measured on noisy discs); a step that raises the
    misfit is halved instead, so the fit settles on the kink.
    """
    n = data.size
    model, dmodel = np.empty(n), np.empty((n, 3))
    J = np.empty((n, 4))
    JtJ, Jtr = np.empty((4, 4)), np.empty(4)
    dd = 0.0
    for i in range(n):
        dd += data[i] * data[i]
    kept, step = theta.copy(), np.zeros(3)
    kept_cost = np.inf
    for _ in range(_DISC_EVALUATIONS):
        _disc_model(theta[0], theta[1], theta[2], xcols, yrows, model, dmodel)
        mm, dm = 0.0, 0.0
        for i in range(n):
            mm += model[i] * model[i]
            dm += data[i] * model[i]
        cost = dd - dm * dm / mm if mm > 0.0 else np.inf
        if cost > kept_cost:  # overshot: halve the step from the kept posture
            step *= 0.5
            _step_from(kept, step, theta)
            if abs(step[0]) < _DISC_TOLERANCE_PX and abs(step[1]) < _DISC_TOLERANCE_PX:
                _copy(theta, kept)
                return True
            continue
        if mm <= 0.0:
            return False
        _copy(kept, theta)
        kept_cost = cost
        a = dm / mm
        for i in range(n):
            J[i, 0], J[i, 1], J[i, 2] = a * dmodel[i, 0], a * dmodel[i, 1], a * dmodel[i, 2]
            J[i, 3] = model[i]
        for p in range(4):
            acc = 0.0
            for i in range(n):
                acc += J[i, p] * (data[i] - a * model[i])
            Jtr[p] = acc
            for q in range(p + 1):
                acc = 0.0
                for i in range(n):
                    acc += J[i, p] * J[i, q]
                JtJ[p, q] = acc
                JtJ[q, p] = acc
            JtJ[p, p] *= 1.0 + 1e-6
        delta = solve_spd(JtJ, Jtr)
        for p in range(3):
            step[p] = max(-0.5, min(0.5, delta[p]))
        _step_from(kept, step, theta)
        if theta[2] <= 0.25:
            return False
        if abs(step[0]) < _DISC_TOLERANCE_PX and abs(step[1]) < _DISC_TOLERANCE_PX:
            return True
    return abs(step[1]) < 10 * _DISC_TOLERANCE_PX
