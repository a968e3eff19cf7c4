"""Images that do not determine a DOF: the tolerance an image's residual sets, and a witness.

With sliding skin markers the true posture is not the minimum of Eq. 5, and a short chain
seen in two views has flat directions (rotation about a segment's long axis, depth): an
image may have a single minimum and still not place a DOF within
:data:`UNDETERMINED_DEG`. :func:`residual_tolerance` says how much objective an image's
own residual cannot tell apart; :func:`undetermined_alternative` finds a posture at least
:data:`UNDETERMINED_DEG` away in some DOF within it, which ``core.fit`` gives the image as
its alternative (``alternative_deg``, ``core.ambiguity`` for the other alternatives).
Skin markers slide in 3D, and every view sees a marker's slide alike, so the residual of a
multi-camera image hides more than independent scatter would: each DOF's interval is the
wider of the two readings (:func:`shared_scatter_inflation`), the second for the share of
the residual that is 3D scatter; the share that is each view's image shifted as a whole (a
calibration's error) is read by its own, narrower, covariance (:func:`residual_shares`).
"""

from __future__ import annotations

import math
from statistics import NormalDist

import numpy as np

from core import _kernels
from core.ambiguity import Candidate, angle_gaps, plain_error
from core.ceilings import MAX_LOST_SHARE
from core.claims import FUSED_PX
from core.error import Detections, fused_marker_diameter, marker_errors, nearest_detection, view_offsets
from core.model import KinematicModel
from core.part_objective import world_frames
from core.rig import Rig

__all__ = ["PROFILE_STEPS", "UNDETERMINED_DEG", "WITNESS_DOUBLINGS", "borrowed_projections",
           "confidence_chi2", "crossed_markers", "fused_projections", "hidden_projections",
           "interval_chi2", "moved_projections", "residual_shares", "residual_tolerance",
           "rigid_markers", "scatter_error", "shared_scatter_inflation", "typical_inflation",
           "undetermined_alternative", "unseen_markers"]

# An image does not determine a DOF when a posture this far from its fit in that DOF (degrees,
# the "more than 10 degrees off the truth") explains it within its tolerance.
UNDETERMINED_DEG = 10.0
CONFIDENCE = 0.99  # postures inside the image's 99 % confidence region are not told apart
_Z_CONFIDENCE = 2.3263  # the standard normal quantile at CONFIDENCE
WITNESS_DOUBLINGS = 3  # a witness is pushed to 2, 4, 8 × UNDETERMINED_DEG while it stays within
PROFILE_STEPS = 10  # LM steps of a witness refined with its DOF held
_SCREEN = 4.0  # DOFs whose linearised rise is above this many tolerances are not tried
_NEAR = 2.0  # a straight step at most this many tolerances beyond the limit is refined
def confidence_chi2(k: int) -> float:
    """χ² of ``k`` degrees of freedom at :data:`CONFIDENCE` (Wilson–Hilferty: within 1 % of
    the exact quantile for every k).

    >>> round(confidence_chi2(1), 2), round(confidence_chi2(6), 2)
    (6.59, 16.84)
    """
    c = 2.0 / (9.0 * k)
    return k * (1.0 - c + _Z_CONFIDENCE * math.sqrt(c)) ** 3


def interval_chi2(intervals: int) -> float:
    """χ² of one degree of freedom at which ``intervals`` one-DOF confidence intervals hold
    together at :data:`CONFIDENCE`: each at 1 − (1 − CONFIDENCE) / ``intervals``
    (Bonferroni), exactly (the square of the two-sided normal quantile).

    An image is trusted in every DOF at once: the witness tries each rotational DOF, and at
    99 % apiece one DOF in a hundred would lie outside its interval by chance, the more
    often the more DOFs a model has.

    >>> round(interval_chi2(1), 2), round(interval_chi2(16), 2)
    (6.63, 11.7)
    """
    z = NormalDist().inv_cdf(1.0 - (1.0 - CONFIDENCE) / (2.0 * max(intervals, 1)))
    return z * z


def hidden_projections(distances: np.ndarray, penalty: float) -> np.ndarray:
    """(V, M) bool: the projections whose ``distances`` (V, M) px to the nearest blob of
    their view (``core.error.marker_errors``; NaN in a view without blobs) exceed
    ``penalty``: markers hidden from that camera, charged their distance to some other blob.
    None of them (all False) where more than ``core.ceilings.MAX_LOST_SHARE`` of the compared
    projections are that far: that fit is not one with a few hidden markers."""
    far = np.isfinite(distances) & (distances > penalty)
    if np.count_nonzero(far) > MAX_LOST_SHARE * np.count_nonzero(np.isfinite(distances)):
        return np.zeros_like(far)
    return far


def unseen_markers(distances: np.ndarray, penalty: float, borrowed: np.ndarray | None = None,
                   fused: np.ndarray | None = None, crossed: np.ndarray | None = None) -> np.ndarray:
    """(M,) bool: the markers that no camera sees in this image, or one alone of three or
    more. The image then does not place the DOFs only they place (a claw's tarsus):
    :func:`undetermined_alternative` leaves them out.

    A projection sees its marker where it lies on a blob: not hidden
    (:func:`hidden_projections` of ``distances`` (V, M) px, NaN in a view without blobs) and
    not on another marker's blob (``borrowed`` (V, M) bool, :func:`borrowed_projections`).
    A marker is unseen where one of its projections is hidden and not fused (``fused`` (V,
    M) bool, :func:`fused_projections`: big markers whose joints touch fuse in every view,
    the merged blob's centroid far from each), and it is seen in no view with blobs, in
    one alone where three or more have blobs, or only where it is fused (on no blob of its
    own). A marker ``crossed`` (M,) bool (:func:`crossed_markers`: at one point with a marker
    on another joint in every view) is unseen with no projection hidden. ``borrowed``, ``fused`` and
    ``crossed`` are none where not given.

    Why one of three: a marker hidden from every camera is charged its distance to the
    nearest blob, and a posture that puts it on some other blob in one view (a ghost, 3 px
    away) scores lower than the truth; seen by one camera of four, a spider's claw that
    none saw was placed that way, its metatarsus 44° off and ``ok``. A marker that two
    cameras see is placed by both; with two views, one alone is how the paper's locust is
    filmed.

    Why another marker's blob does not see it: a human's finger marker hidden from all six
    cameras was placed 3-4 px from the wrist marker's blob in two of them (the objective
    reads the two as fused there), its wrist flexion 69° off at its range limit, ``ok``, with
    no witness. Why fused views alone do not: a stick insect's claw hidden from both
    cameras was placed exactly on the coxa's blob in one of them, γ 111° off, ``ok``, and its
    only alternative as far off. A marker fused in some views and on its own blob in
    another is seen in all of them (bigger markers fuse often).
    """
    views = np.isfinite(distances).any(axis=1)
    hidden = hidden_projections(distances, penalty)
    none = np.zeros_like(hidden)
    fused = none if fused is None else fused
    on_blob = (~hidden & ~(none if borrowed is None else borrowed))[views]
    seen = np.where((on_blob & ~fused[views]).any(axis=0), np.count_nonzero(on_blob, axis=0), 0)
    if not views.any():
        return np.zeros(len(seen), bool)
    crossed = np.zeros(len(seen), bool) if crossed is None else crossed
    return (seen < (2 if np.count_nonzero(views) >= 3 else 1)) & ((hidden & ~fused).any(axis=0) | crossed)


def borrowed_projections(projected: np.ndarray, detections: Detections) -> np.ndarray:
    """(V, M) bool: the projections ``projected`` (V, M, 2) whose nearest blob another
    projection lies nearer to, where the blob is not the two of them fused (their midpoint
    farther than ``core.claims.FUSED_PX`` from it): a marker on another marker's blob.
    False in a view without blobs.

    >>> det = Detections.from_views([[[0.0, 0.0], [10.0, 0.0]]])
    >>> borrowed_projections(np.array([[[0.1, 0.0], [3.0, 0.0], [9.0, 0.0], [11.0, 0.0]]]), det).tolist()
    [[False, True, False, False]]
    """
    out = np.zeros(projected.shape[:2], dtype=bool)
    for v in range(projected.shape[0]):
        points = detections.view(v)
        if not len(points):
            continue
        nearest, d2 = nearest_detection(projected[v], points)
        # (M, M): projection j lies on projection i's nearest blob, nearer to it
        shared = (nearest[:, None] == nearest[None, :]) & (d2[None, :] < d2[:, None])
        i, j = np.nonzero(shared)
        midpoint = 0.5 * (projected[v, i] + projected[v, j]) - points[nearest[i], :2]
        out[v, i[np.einsum("ij,ij->i", midpoint, midpoint) > FUSED_PX ** 2]] = True
    return out


def scatter_error(q: np.ndarray, detections: Detections, model: KinematicModel, rig: Rig,
                  offsets: np.ndarray, penalty: float, fusion_px: float) -> float:
    """Eq. 5 (px) of posture ``q`` (D,) read as the markers' scatter about the model: the
    sum of the compared projections' distances to their nearest blob
    (``core.error.marker_errors``, views shifted by ``offsets`` (V, 2)), the
    :func:`hidden_projections` (farther than ``penalty``) and the :func:`fused_projections`
    (closer than ``fusion_px`` to another on the same blob) each counted at the mean of the
    others, or at its own distance where that is less (never above the plain Eq. 5). A
    hidden marker is not scatter: read as scatter, one made a noise-free image read as one
    with sliding skin. Nor is a fused blob's offset from its markers, half their separation:
    read as scatter, it gave 8 of 60 noise-free stick insect images, fitted within 0.04°, a
    witness 10-20° away.
    NaN with no compared projection, 0 where every one is hidden or fused.
    """
    projected = rig.project(model.marker_positions(q)) + offsets[:, None, :]
    distances = marker_errors(projected, detections)
    compared = np.isfinite(distances)
    if not compared.any():
        return math.nan
    kept = compared & ~hidden_projections(distances, penalty) & ~fused_projections(projected, detections,
                                                                                    fusion_px)
    if not kept.any():
        return 0.0
    typical = float(np.mean(distances[kept]))
    return float(distances[kept].sum() + np.minimum(distances[compared & ~kept], typical).sum())


def fused_projections(projected: np.ndarray, detections: Detections, fusion_px: float) -> np.ndarray:
    """(V, M) bool: the projections ``projected`` (V, M, 2) that share their nearest blob with
    another projection closer than ``fusion_px`` to them, as the objective fuses markers
    (``core._kernels.fuse_projections``): one blob between them, half their separation
    from each. False in a view without blobs. Projections far apart on one blob are not
    fused: a posture with markers on other markers' blobs is a wrong fit, not a fusion.

    >>> det = Detections.from_views([[[0.0, 0.0], [10.0, 0.0]]])
    >>> fused_projections(np.array([[[-1.0, 0.0], [1.0, 0.0], [9.0, 0.0], [30.0, 0.0]]]), det, 8.0).tolist()
    [[True, True, False, False]]
    """
    out = np.zeros(projected.shape[:2], dtype=bool)
    for v in range(projected.shape[0]):
        points = detections.view(v)
        if len(points):
            out[v] = _fused_in_view(projected[v], nearest_detection(projected[v], points)[0], fusion_px)
    return out


def _fused_in_view(projected: np.ndarray, nearest: np.ndarray, fusion_px: float) -> np.ndarray:
    """:func:`fused_projections` of one view: ``projected`` (M, 2), each projection's
    nearest blob ``nearest`` (M,)."""
    return _fused_pairs(projected, nearest, fusion_px).any(axis=1)


def _fused_pairs(projected: np.ndarray, nearest: np.ndarray, fusion_px: float) -> np.ndarray:
    """(M, M) bool, symmetric: projections ``projected`` (M, 2) of one view closer than
    ``fusion_px`` to each other on one blob (``nearest`` (M,), each one's nearest blob)."""
    return _close_pairs(projected, fusion_px) & (nearest[:, None] == nearest[None, :])


def _close_pairs(projected: np.ndarray, px: float) -> np.ndarray:
    """(..., M, M) bool, symmetric: two distinct projections of ``projected`` (..., M, 2),
    in one view, closer than ``px`` to each other."""
    gap = projected[..., :, None, :] - projected[..., None, :, :]
    near = np.einsum("...ijk,...ijk->...ij", gap, gap) < px * px
    return near & ~np.eye(projected.shape[-2], dtype=bool)


def crossed_markers(projected: np.ndarray, detections: Detections, fusion_px: float,
                    rigid: np.ndarray) -> np.ndarray:
    """(M,) bool: the markers at one point with a marker on another joint (``rigid`` (M, M)
    bool, :func:`rigid_markers`, marks the pairs on one joint): on one blob with it, less
    than half a marker's diameter away (``core.error.fused_marker_diameter``), in every view
    with blobs, two or more. Two real markers cannot lie that close in two views (each is a
    marker's diameter across); the images cannot tell one
    marker there from two, so they place neither segment's DOFs that only it places.

    Why: a rat whose right ankle and toe no camera saw was fitted with its right leg folded
    onto its left, the two ankles and the two toes 0.03 px apart in all three views; no
    projection of theirs looked hidden, and hip flexion was 35° off, ``ok``, with no
    alternative. A random tree of one branch on a free root (one chain) had the branch's
    first marker, hidden from both cameras, put on a root marker's blob, 0.9 and 0.2 px from
    it: the branch's roll 17° off, ``ok``, with no alternative (docs/BENCH_SUBJECTS.md, stop
    48). Why half a diameter, not ``fusion_px``: a walking fly's middle and hind knees, 9 px
    markers, come within ``fusion_px`` (17.8 px) in every view of 15 images in 60, 7-17 px
    apart in the view that shows them farthest apart. Why not two markers on one joint: a
    model may place them that close, and no posture moves them apart.
    """
    views = np.flatnonzero(detections.counts)
    if len(views) < 2:
        return np.zeros(projected.shape[1], bool)
    limit = 0.5 * fused_marker_diameter(fusion_px)
    crossed = _close_pairs(projected[views], limit).all(axis=0) & ~rigid
    for v in views if crossed.any() else ():  # close in every view: on one blob in each?
        nearest = nearest_detection(projected[v], detections.view(v))[0]
        crossed = crossed & (nearest[:, None] == nearest[None, :])
    return crossed.any(axis=1)


def rigid_markers(model: KinematicModel) -> np.ndarray:
    """(M, M) bool: True where two markers ride on one joint (their distance is the model's,
    in every posture), False elsewhere."""
    joint = model.arrays.marker_joint
    return joint[:, None] == joint[None, :]


def residual_tolerance(error_px: float, compared: int, n_dofs: int, tested_dofs: int,
                       intervals: int = 1) -> float:
    """Pixels of Eq. 5 within which an image cannot tell postures apart, from its own residual.

    ``error_px`` is the fit's plain Eq. 5 error over ``compared`` marker projections, for a
    model of ``n_dofs`` DOFs; ``tested_dofs`` is how many DOFs the postures compared may
    differ in: 1 for one DOF's confidence interval, ``n_dofs`` for another minimum anywhere.
    With ``tested_dofs`` 1, ``intervals`` is how many one-DOF intervals must hold together
    (:func:`interval_chi2`); otherwise χ² is :func:`confidence_chi2` of ``tested_dofs``.
    A fit's mean distance ē per projection estimates the per-coordinate scatter σ of the
    markers about the model (slid skin, noise): σ² = ē² · 2/π (a 2-D distance of
    per-coordinate σ has mean σ√(π/2)), times 2n / (2n − D) because the fit absorbs D of
    the 2n coordinates. A posture at the edge of the confidence region raises Σ‖r‖² by
    χ²(tested) · σ² (:func:`confidence_chi2`), so Eq. 5 (Σ‖r‖, distances near ē) by about
    χ² · σ² / (2ē) = χ² · ē · 2n / ((2n − D) π). An image fitted at 1 px a projection
    cannot tell apart postures a few pixels apart; one fitted at 0.05 px can. NaN or no
    projections: 0.

    >>> round(residual_tolerance(8.0, 8, 6, 1), 2), round(residual_tolerance(8.0, 8, 6, 6), 2)
    (3.38, 8.58)
    """
    if compared <= 0 or not math.isfinite(error_px):
        return 0.0
    coords = 2 * compared
    chi2 = interval_chi2(intervals) if tested_dofs == 1 else confidence_chi2(tested_dofs)
    return (chi2 * (error_px / compared) * coords
            / (max(coords - n_dofs, 1) * math.pi))


def undetermined_alternative(
    fit: Candidate,
    detections: Detections,
    *,
    model: KinematicModel,
    rig: Rig,
    floor_px: float,
    residual_px: float = 0.0,
    inflate: bool = True,
    fusion_px: float,
    empty_view_penalty_px: float,
    huber_px: float,
    offsets: np.ndarray | None = None,
    unseen: np.ndarray | None = None,
) -> Candidate | None:
    """A posture at least :data:`UNDETERMINED_DEG` from ``fit`` in some rotational DOF whose
    objective is within ``tolerance_px`` of the fit's, or None: the witness that the image
    does not determine that DOF.

    Each rotational DOF d is moved along its profile, the linearised best way to move d
    with every other DOF following (column d of (JᵀJ)⁻¹, J the Jacobian of the
    projections), by ±:data:`UNDETERMINED_DEG`, then 2, 4, 8 times as far while the
    objective (as the fit's: fusion, a lost marker per view) stays within the tolerance;
    a step that leaves it by less than :data:`_NEAR` tolerances is refined with d held
    (towards the profile's minimum, nonlinear). A step in a DOF the model's markers cannot
    determine in any posture (``model.identifiability``) is refined however far it leaves:
    its flat valley is curved, and a straight step of 10° in a pelvis tilt that the hips
    follow leaves it by tens of pixels. A tree's step is refined on d's part alone, then,
    seen in two views and still beyond the tolerance, on the whole model: there a branch's
    valley can need its neighbours to follow (a branch whose markers fuse with another's),
    and with three or more views the whole-model refinement of every sliding-skin image's
    steps cost up to half the rate (docs/BENCH_SUBJECTS.md, random trees, stop 47).
    DOFs whose linearised rise at the first step is above :data:`_SCREEN` tolerances are
    not tried (most DOFs of a clean image: the search costs a Jacobian and a few errors).
    Of the postures within the tolerance, the one farthest from the fit.

    DOF d's tolerance is the larger of two readings (``core.fit.tolerance_readings``):
    ``floor_px`` per 8 of the projections d moves (:func:`moved_projections`, never less than
    ``floor_px``: a claw's DOF is not given the allowance of a whole hexapod's projections),
    or per 8 of all compared projections where a marker is ``unseen`` (a hidden marker
    may sit on another blob, which no linear profile foresees: with a DOF's floor alone, a
    hexapod image with markers no camera saw was left more than 10° off, ``ok``, without a
    witness),
    and ``residual_px``, the image's one-DOF tolerance read from its residual as scatter
    independent in every projection (:func:`residual_tolerance`), widened to ``residual_px``
    × :func:`shared_scatter_inflation` [d] by the share of the residual that is the markers'
    own 3D scatter (sliding skin, a model's segments off), which every view sees alike
    (not with ``inflate`` False).

    ``unseen`` (M,) bool marks markers no camera sees in this image (:func:`unseen_markers`):
    left out of the profiles and charged the empty-view penalty wherever they project, so
    that a DOF only they place is found undetermined. Judged on their distance to some other
    blob, a spider's metatarsus whose claw was hidden from all four cameras stood 44° off,
    `ok`, with no witness.
    """
    q = fit.dofs
    rot = model.rotational
    compared = detections.views_seen * len(model.markers)
    if not rot.any() or not math.isfinite(fit.error) or max(floor_px, residual_px) <= 0 or compared == 0:
        return None
    off = view_offsets(offsets, rig)
    kin, views, points, start = model.arrays, rig.arrays, detections.kernel_points, detections.start
    hidden = np.zeros(len(model.markers), dtype=bool) if unseen is None else np.asarray(unseen, dtype=bool)
    left_out = (np.ascontiguousarray(np.broadcast_to(hidden, (len(rig.views), len(hidden))))
                if hidden.any() else _kernels.NO_UNSEEN)
    image = _kernels.Image.of(points, start, off, penalty=empty_view_penalty_px, fuse_px=fusion_px,
                              unseen=left_out)
    charged = image._replace(lost_px=image.penalty)  # the objective a fit reports

    def objective(p: np.ndarray) -> float:
        return float(_kernels.posture_error(p, kin, views, charged))

    def pinned(p: np.ndarray, d: int, whole: bool = False) -> np.ndarray:
        """``p`` refined with DOF d held: the whole model, or for a tree (``core.tree``) d's
        part alone, the rest where ``p`` puts it (a leg's DOFs, not all 42), unless ``whole``."""
        dofs, part_kin = np.arange(len(p)), kin
        if model.tree is not None and not whole:
            part = next(x for x in model.tree.parts if d in x.dofs)
            rotation, origin = world_frames(p, model)
            dofs, part_kin = part.dofs, part.at(rotation[part.base], origin[part.base])
        lower, upper = model.lower[dofs].copy(), model.upper[dofs].copy()
        lower[dofs == d] = upper[dofs == d] = p[d]
        out = p.copy()
        posed = image if not hidden.any() or model.tree is None or whole else image._replace(
            unseen=np.ascontiguousarray(left_out[:, part.markers]))
        out[dofs] = _kernels.refine(p[dofs].copy(), _kernels.Bounds(lower, upper), part_kin, views,
                                    posed, float(huber_px), PROFILE_STEPS, _kernels.NO_TARGETS)
        return out

    profiles, moves, inflation = _profiles(q, model, rig, detections, hidden, off, empty_view_penalty_px,
                                           fusion_px, inflate)
    counted = np.full(len(q), float(compared)) if hidden.any() else moved_projections(moves)
    floor = floor_px * np.maximum(1.0, counted / 8.0)
    tolerance = np.maximum(floor, residual_px * inflation)  # (D,) pixels
    mean = max(fit.error / compared, 1e-12)
    # Linearised rise of Eq. 5 at the first step: a projection moved by m from a residual
    # of about ē rises by ~m²/(2ē) while m << ē, by ~m when m >> ē.
    step_moves = UNDETERMINED_DEG * moves
    rise = np.minimum(step_moves, step_moves**2 / (2 * mean)).sum(axis=1)
    screened = rise <= _SCREEN * tolerance
    fitted = objective(q)
    structural = np.isin(model.dof_names, model.identifiability.undetermined)
    two_views = model.tree is not None and detections.views_seen == 2
    best, best_gap = None, UNDETERMINED_DEG
    for d in np.flatnonzero(rot & screened):
        limit = fitted + tolerance[d]
        for sign in (1.0, -1.0):
            for k in range(_first_doubling(best_gap), WITNESS_DOUBLINGS + 1):
                step = sign * UNDETERMINED_DEG * 2**k
                p = np.clip(q + step * profiles[d], model.lower, model.upper)
                value = objective(p)
                if limit < value <= limit + _NEAR * tolerance[d] or (structural[d] and value > limit):
                    p = pinned(p, int(d))
                    value = objective(p)
                    if value > limit and two_views:
                        p = pinned(p, int(d), whole=True)
                        value = objective(p)
                gap = float(angle_gaps(p, q)[rot].max())
                if value > limit or gap < abs(step) * (1 - 1e-9):  # worse, or at a bound
                    break
                if gap >= best_gap:
                    best, best_gap = p, gap
    if best is None:
        return None
    return Candidate(best, plain_error(best, detections, model, rig, off, image.penalty), objective(best),
                     minimum=False)


def _first_doubling(gap: float) -> int:
    """The first doubling k whose step (``UNDETERMINED_DEG`` × 2^k) reaches ``gap`` (degrees), the
    farthest witness found so far: a nearer step cannot replace it, and whether the profile
    stays within the tolerance up to there does not matter to a posture that is within it.

    >>> [_first_doubling(g) for g in (10.0, 10.5, 40.0, 500.0)]
    [0, 1, 2, 3]
    """
    k = 0
    while k < WITNESS_DOUBLINGS and UNDETERMINED_DEG * 2**k < gap:
        k += 1
    return k


def _profiles(q: np.ndarray, model: KinematicModel, rig: Rig, detections: Detections,
              unseen: np.ndarray, offsets: np.ndarray, penalty: float,
              fusion_px: float, inflate: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Profile directions (D, D), row d the change of every DOF per unit change of DOF d;
    (D, P) how far each of the P compared marker projections moves along each, pixels per
    unit; and (D,) each DOF's :func:`shared_scatter_inflation`, of the image's own residual
    (views shifted by ``offsets`` (V, 2); hidden and fused projections read as no residual,
    :func:`_residual_vectors`), ones without ``inflate`` (four fifths of the cost: SVDs).
    From the Jacobian J of the projections in the views
    with detections, less those of the ``unseen`` (M,) markers (forward differences;
    linearised least squares: column d of (JᵀJ)⁻¹)."""
    D = len(q)
    h = 1e-3
    postures = np.repeat(q[None], D + 1, axis=0)
    postures[1:] += np.eye(D) * h
    positions = model.marker_positions(postures)  # (D + 1, M, 3)
    proj = rig.project(positions)  # (D + 1, V, M, 2)
    compared = (np.asarray(detections.counts) > 0)[:, None] & ~unseen[None, :]  # (V, M)
    J = ((proj[1:] - proj[:1])[:, compared] / h).reshape(D, -1).T  # (2P, D)
    A = J.T @ J
    A += np.eye(D) * (1e-9 * max(float(np.trace(A)) / D, 1e-12))  # a DOF no marker moves
    C = np.linalg.inv(A)
    profiles = (C / np.diag(C)[None, :]).T
    moves = np.linalg.norm((J @ profiles.T).T.reshape(D, -1, 2), axis=2)
    if not inflate:
        return profiles, moves, np.ones(D)
    shared = _point_jacobian(positions[0], rig, compared)
    residual = _residual_vectors(proj[0] + offsets[:, None, :], detections, compared, penalty, fusion_px)
    return profiles, moves, shared_scatter_inflation(J, C, shared, residual, _view_shifts(compared))


def _view_shifts(compared: np.ndarray) -> np.ndarray:
    """(2P, 2V) the compared projections (``compared`` (V, M) bool, rows as the profiles'
    Jacobian) moved by each view's image shifted one pixel in u or v."""
    views = np.nonzero(compared)[0]
    T = np.zeros((2 * len(views), 2 * compared.shape[0]))
    rows = np.arange(len(views))
    T[2 * rows, 2 * views] = 1.0
    T[2 * rows + 1, 2 * views + 1] = 1.0
    return T


def moved_projections(moves: np.ndarray) -> np.ndarray:
    """(D,) how many projections each profile moves: the participation ratio
    (Σ m)² / Σ m² of its moves ``moves`` (D, P), k where it moves k projections alike, 0
    where it moves none.

    >>> moved_projections(np.array([[1.0, 1.0, 1.0, 0.0], [0.0, 0.0, 0.0, 0.0]])).tolist()
    [3.0, 0.0]
    """
    square = np.sum(moves * moves, axis=1)
    return np.divide(np.sum(moves, axis=1) ** 2, square, out=np.zeros(len(moves)), where=square > 0)


def _residual_vectors(projected: np.ndarray, detections: Detections, compared: np.ndarray,
                      penalty: float, fusion_px: float) -> np.ndarray:
    """(2P,) each compared projection's offset (u, v) from its nearest blob, pixels, rows
    ordered as the profiles' Jacobian; 0 for a projection farther than ``penalty`` (a
    hidden marker is not scatter) and for :func:`fused_projections` (closer than
    ``fusion_px`` to another on one blob, which lies between them, half their separation
    from each: read as scatter, the mouse's fused toes made a calibration's shift of its
    views look like noise). ``projected`` (V, M, 2), ``compared`` (V, M) bool."""
    out = np.zeros(projected.shape)
    for v in np.flatnonzero(compared.any(axis=1)):
        points = detections.view(v)
        nearest, d2 = nearest_detection(projected[v], points)
        kept = (d2 <= penalty * penalty) & ~_fused_in_view(projected[v], nearest, fusion_px)
        out[v] = np.where(kept[:, None], projected[v] - points[nearest, :2], 0.0)
    return out[compared].reshape(-1)


def _point_jacobian(points: np.ndarray, rig: Rig, compared: np.ndarray) -> np.ndarray:
    """(2P, 3M) derivative of the P projections that ``compared`` (V, M) marks, rows ordered
    as the profiles' Jacobian (view, marker, u/v), by each marker's world position
    ``points`` (M, 3), model units (forward differences)."""
    M = len(points)
    h = 1e-3 * max(float(np.ptp(points, axis=0).max()), 1.0)
    moved = np.repeat(points[None], 4, axis=0)  # unmoved, then each axis
    moved[1:] += np.eye(3)[:, None, :] * h
    proj = rig.project(moved)[:, compared]  # (4, P, 2)
    G = (proj[1:] - proj[:1]) / h  # (3 axes, P, 2)
    P = G.shape[1]
    B = np.zeros((P, 2, M, 3))
    B[np.arange(P), :, np.nonzero(compared)[1], :] = G.transpose(1, 2, 0)  # marker m's rows move with m alone
    return B.reshape(2 * P, 3 * M)


def typical_inflation(compared: int, n_markers: int, n_dofs: int) -> float:
    """About what :func:`shared_scatter_inflation` comes to for views around the animal,
    from counts alone: (2P − D) / (3M − D) for ``compared`` P marker projections of
    ``n_markers`` M markers and ``n_dofs`` D DOFs, at least 1 (one view, which cannot see a
    slide in depth); the residual's coordinates over the markers' own, each less the D
    the fit absorbs. Costs no Jacobian: it says where the witness is worth looking for.

    >>> round(typical_inflation(162, 27, 48), 2), typical_inflation(4, 4, 5)
    (8.36, 1.0)
    """
    return max(1.0, (2 * compared - n_dofs) / max(3 * n_markers - n_dofs, 1))


def shared_scatter_inflation(J: np.ndarray, C: np.ndarray, B: np.ndarray,
                             residual: np.ndarray | None = None,
                             shifts: np.ndarray | None = None) -> np.ndarray:
    """(D,) how much wider each DOF's confidence interval is than :func:`residual_tolerance`
    reads it (scatter independent in each projection), given what the residual is.

    ``J`` (2P, D) is the projections' Jacobian by the DOFs, ``C`` (D, D) its (JᵀJ)⁻¹ and
    ``B`` (2P, 3M) the projections' Jacobian by the markers' world positions. With marker
    scatter Σ = σ₃² BBᵀ (a skin marker sliding, a model's segment off, seen alike by every
    view) the residual's expected square is σ₃² tr((I − J C Jᵀ) BBᵀ) and the fit's
    covariance σ₃² C JᵀBBᵀJ C; read as independent scatter, the same residual gives the
    covariance σ² C with σ² = residual² / (2P − D). The ratio of the two, per DOF, is the
    factor by which the tolerance of a one-DOF interval grows: about (2P − D) / (3M − D)
    for views around the animal (3 for three cameras around a rat), since a marker slid in
    3D moves alike in every view and more views do not average it out; 1 for a single
    orthographic view, which cannot see the slide in depth. Without ``residual``, all of
    it is read as 3D scatter: at least 1, the wider of the two readings.

    Given the image's ``residual`` (2P,) px, each share of it (:func:`residual_shares`) is
    read as what it is: independent scatter as such, 3D scatter as above (the wider of the
    two readings for those two shares together), and a shift of each view's image as a
    whole (``shifts`` (2P, 2V), column (v, u/v) 1 on view v's u or v rows: a calibration's
    error) by its own covariance C JᵀTTᵀJ C, which moves a posture far less than scatter
    of that size in every projection would: the factor may then be below 1.
    """
    P2, D = J.shape
    JB = J.T @ B  # (D, 3M)
    unexplained = _left_by_fit(B, JB, C)
    if unexplained <= 0 or P2 <= D:
        return np.ones(D)
    read_3d = (P2 - D) / unexplained * _variance_ratio(C, JB)
    if residual is None:
        return np.maximum(1.0, read_3d)
    independent, scattered, shifted = residual_shares(J, C, B, shifts, residual)
    inflation = np.maximum(independent + scattered, independent + scattered * read_3d)
    if shifted > 0 and shifts is not None:
        JT = J.T @ shifts  # (D, 2V)
        inflation = inflation + shifted * (P2 - D) / _left_by_fit(shifts, JT, C) * _variance_ratio(C, JT)
    return inflation


def _left_by_fit(X: np.ndarray, JX: np.ndarray, C: np.ndarray) -> float:
    """tr(Xᵀ R X), R = I − J C Jᵀ: how much of unit scatter along the columns of ``X`` (2P, k)
    the fit leaves in the residual, from ``JX`` = JᵀX (D, k) and ``C`` = (JᵀJ)⁻¹ (D, D)."""
    return float(np.sum(X * X) - np.sum(JX * (C @ JX)))


def _variance_ratio(C: np.ndarray, JX: np.ndarray) -> np.ndarray:
    """(D,) diag(C JX JXᵀ C) / diag(C): a DOF's variance under unit noise along X (``JX`` =
    JᵀX) against under unit noise in every projection."""
    CJX = C @ JX
    return np.sum(CJX * CJX, axis=1) / np.diag(C)


def residual_shares(J: np.ndarray, C: np.ndarray, B: np.ndarray, shifts: np.ndarray | None,
                    residual: np.ndarray) -> tuple[float, float, float]:
    """The shares of ``residual``'s (2P,) energy that are scatter independent in every
    projection (noise), the markers' own 3D scatter, and a shift of each view's image
    (``shifts`` (2P, 2V), or None: none); they sum to 1. All 3D scatter where they cannot
    be told apart.

    The fit leaves the residual r in the range of R = I − J C Jᵀ (``J`` (2P, D), ``C`` its
    (JᵀJ)⁻¹). 3D scatter (``B`` (2P, 3M), the projections by the markers' positions) lies in
    the range of RB, of rank k₁; shifts beyond it in that of RT, k₂ more directions;
    independent scatter of variance σ² fills all 2P − D directions alike. The
    k₃ = 2P − D − k₁ − k₂ directions left hold independent scatter alone and measure σ²,
    pooled with the others where they hold less per direction (:func:`_pooled_noise`);
    then RT's own directions measure the shifts, and RB's the 3D scatter (moments, each
    variance at least 0).
    """
    P2, D = J.shape

    def R(X: np.ndarray) -> np.ndarray:  # (I − J C Jᵀ) X without the (2P, 2P) matrix
        return X - J @ (C @ (J.T @ X))

    r = R(residual)
    total = float(r @ r)
    S1 = _basis(R(B))
    RT = np.zeros((P2, 0)) if shifts is None else R(shifts)
    RT_beyond = RT - S1 @ (S1.T @ RT)
    S2 = _basis(RT_beyond)
    k1, k2 = S1.shape[1], S2.shape[1]
    k3 = P2 - D - k1 - k2
    if total <= 0 or P2 - D - k1 <= 0:
        return 0.0, 1.0, 0.0
    o1, o2 = float(np.sum((S1.T @ r) ** 2)), float(np.sum((S2.T @ r) ** 2))
    shifts_all, shifts_beyond = float(np.sum(RT * RT)), float(np.sum(RT_beyond * RT_beyond))
    noise, pooled = _pooled_noise(total - o1 - o2, k3, {"3d": (o1, k1), "shifts": (o2, k2)})
    shift = 0.0 if "shifts" in pooled or not k2 else max(0.0, o2 - noise * k2) / shifts_beyond
    shared = 0.0 if "3d" in pooled else max(0.0, o1 - noise * k1 - shift * (shifts_all - shifts_beyond))
    energies = np.array([noise * (P2 - D), shared, shift * shifts_all])
    if energies.sum() <= 0:
        return 0.0, 1.0, 0.0
    independent, scattered, shifted = energies / energies.sum()
    return float(independent), float(scattered), float(shifted)


def _pooled_noise(alone: float, dims: int, others: dict[str, tuple[float, int]]) -> tuple[float, set[str]]:
    """The independent scatter's variance per direction, and which of ``others`` hold
    nothing more. ``alone`` is the residual's energy in the ``dims`` directions only noise
    reaches; ``others`` the (energy, directions) of subspaces where noise adds to another
    kind of scatter, so that noise can only be less per direction there. A subspace whose
    energy per direction is below the pooled estimate is pooled into it (its other kind
    read as none): a few noise-only directions alone would give a wild estimate (the
    mouse's two views leave one). Without such directions (the locust's chain in two
    views), the pool starts from the subspace holding least per direction: noise holds no
    more than that anywhere.

    >>> noise, pooled = _pooled_noise(1.77, 1, {"3d": (1.22, 68), "shifts": (25.5, 1)})
    >>> round(noise, 4), sorted(pooled)
    (0.0433, ['3d'])
    >>> _pooled_noise(7.0, 7, {"3d": (60.0, 68), "shifts": (0.5, 1)})[1] == {"3d", "shifts"}
    True
    >>> noise, pooled = _pooled_noise(0.0, 0, {"3d": (0.61, 10), "shifts": (5.85, 1)})
    >>> round(noise, 3), sorted(pooled)
    (0.061, ['3d'])
    """
    pooled: set[str] = set()
    while True:
        below = [name for name, (energy, k) in others.items()
                 if name not in pooled and k > 0 and (dims <= 0 or energy / k < alone / dims)]
        if not below:
            return (alone / dims if dims > 0 else 0.0), pooled
        name = min(below, key=lambda n: others[n][0] / others[n][1])
        alone, dims = alone + others[name][0], dims + others[name][1]
        pooled.add(name)


def _basis(A: np.ndarray) -> np.ndarray:
    """An orthonormal basis (n, k) of the range of ``A`` (n, m)."""
    if A.shape[1] == 0:
        return np.zeros((A.shape[0], 0))
    U, s, _ = np.linalg.svd(A, full_matrices=False)
    return U[:, : int(np.count_nonzero(s > 1e-9 * max(float(s[0]), 1e-300)))]
