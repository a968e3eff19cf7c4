"""Images that do not determine a DOF get an alternative; determined ones do not (core.undetermined).

With markers off the model by a pixel (sliding skin), the tolerance within which postures
count as alike grows with the image's own residual, and a DOF that can move more than
``UNDETERMINED_DEG`` within it is reported through ``alternative_deg``.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from tree_subjects import detections, insect, movement, ring_rig

from bench.animals import (
    FAR_OFF_DEG,
    angle_errors,
    far_off_unflagged,
    fit_flags,
    fit_params,
    render_and_detect,
)
from bench.animals import fit as bench_fit
from bench.random_trees import filmed, random_model
from bench.subjects import load
from bench.witness import slid_detections, witnesses
from core.ambiguity import Candidate, angle_gaps, plain_error
from core.error import Detections, marker_errors, view_error, view_offsets
from core.examples import EXAMPLES
from core.fit import FitParams, Status, _undetermined_witness, alternative_tolerance, tolerance_readings
from core.histogram import Histograms
from core.model import KinematicModel
from core.refine import refine
from core.rig import Rig
from core.sequence import fit_sequence
from core.undetermined import (
    UNDETERMINED_DEG,
    confidence_chi2,
    crossed_markers,
    hidden_projections,
    interval_chi2,
    residual_shares,
    residual_tolerance,
    rigid_markers,
    scatter_error,
    shared_scatter_inflation,
    undetermined_alternative,
    unseen_markers,
)

# The stick insect with its tibia almost straight (gamma near its 10 deg minimum): psi turns
# the leg about the femur, on whose axis the femur marker sits, so only the tibia marker's
# small sideways swing tells psi; a pixel of marker scatter hides tens of degrees of it.
STICK_STRAIGHT = np.array([0.0, 10.0, 190.0, 10.0, 15.0, 12.0])
LOCUST = np.array([160.0, 15.0, 3.0, 20.0, 80.0])


def _subject(name: str) -> tuple[KinematicModel, Rig]:
    return (KinematicModel.from_xml(EXAMPLES / name / "model.xml"),
            Rig.from_json(EXAMPLES / name / "rig.json"))


def _scattered(model: KinematicModel, rig: Rig, q: np.ndarray, px: float, seed: int) -> Detections:
    """Exact projections of ``q``, each moved by a normal scatter of ``px`` per coordinate."""
    proj = rig.project(model.marker_positions(q))
    return Detections.from_views(list(proj + np.random.default_rng(seed).normal(0, px, proj.shape)))


def _witness(model: KinematicModel, rig: Rig, det: Detections, q: np.ndarray):
    fit = refine(q, det, model=model, rig=rig)
    error = view_error(fit, det, model=model, rig=rig)
    floor, residual = tolerance_readings(FitParams(), det, model, error, 1)
    found = undetermined_alternative(Candidate(fit, error, error), det, model=model, rig=rig,
                                     floor_px=FitParams().alternative_tolerance_px,
                                     residual_px=residual, fusion_px=0.0,
                                     empty_view_penalty_px=5.0, huber_px=1.0)
    return fit, error, max(floor, residual), found


def test_chi2_quantiles_are_within_one_percent_of_the_table():
    for k, exact in ((1, 6.635), (2, 9.210), (6, 16.812), (42, 66.206)):
        assert confidence_chi2(k) == pytest.approx(exact, rel=0.01)


def test_intervals_holding_together_are_each_at_the_bonferroni_level():
    # χ²(1) quantiles from the table: 99 %, 99.9 %, and 99.9375 % (0.01 shared by 16 intervals).
    for intervals, exact in ((1, 6.635), (10, 10.828), (16, 11.700)):
        assert interval_chi2(intervals) == pytest.approx(exact, rel=1e-3)
    assert interval_chi2(1) == pytest.approx(confidence_chi2(1), rel=0.01)


def test_the_residual_tolerance_per_projection_arithmetic():
    # 8 px over 8 projections: 1 px each; 16 coordinates, 6 DOFs absorbed.
    assert residual_tolerance(8.0, 8, 6, 1) == pytest.approx(interval_chi2(1) * 1.0 * 16 / (10 * math.pi))
    # Six one-DOF intervals holding together: each at 1 - 0.01/6.
    assert residual_tolerance(8.0, 8, 6, 1, 6) == pytest.approx(interval_chi2(6) * 1.0 * 16 / (10 * math.pi))
    # Linear in the mean distance per projection: the same mean over 80 projections gives
    # about the same tolerance (a little less: the DOFs absorb a smaller share).
    assert residual_tolerance(16.0, 8, 6, 1) == pytest.approx(2 * residual_tolerance(8.0, 8, 6, 1))
    assert residual_tolerance(80.0, 80, 6, 1) < residual_tolerance(8.0, 8, 6, 1)
    assert residual_tolerance(80.0, 80, 6, 1) == pytest.approx(
        interval_chi2(1) * 160 / (154 * math.pi))
    assert residual_tolerance(8.0, 8, 6, 6) > residual_tolerance(8.0, 8, 6, 1)
    assert residual_tolerance(math.nan, 8, 6, 1) == 0.0
    assert residual_tolerance(1.0, 0, 6, 1) == 0.0


def test_clean_images_keep_the_fixed_tolerance_and_zero_turns_it_off():
    model, _ = _subject("locust_hind_leg")
    det = Detections.from_views([np.zeros((4, 2))] * 2)  # 4 markers x 2 views: 8 projections
    assert alternative_tolerance(FitParams(), det, model, 0.4, 5) == 0.5
    assert alternative_tolerance(FitParams(), det, model, 8.0, 1) == pytest.approx(
        residual_tolerance(8.0, 8, 5, 1))
    assert alternative_tolerance(FitParams(alternative_tolerance_px=0.0), det, model, 8.0, 1) == 0.0


def test_an_undetermined_dof_gets_a_witness_within_the_tolerance():
    model, rig = _subject("stick_insect_front_leg")
    det = _scattered(model, rig, STICK_STRAIGHT, 1.0, seed=1)
    fit, error, tolerance, found = _witness(model, rig, det, STICK_STRAIGHT)
    assert found is not None
    gaps = angle_gaps(found.dofs, fit)[model.rotational]
    assert gaps.max() >= UNDETERMINED_DEG
    assert gaps[model.dof_names.index("psi")] >= UNDETERMINED_DEG  # the femur's own axis
    assert found.objective <= error + tolerance
    assert found.error == pytest.approx(view_error(found.dofs, det, model=model, rig=rig))
    assert np.all((found.dofs >= model.lower) & (found.dofs <= model.upper))


@pytest.mark.parametrize("px", [0.0, 0.3])
def test_a_determined_posture_gets_no_witness(px):
    model, rig = _subject("locust_hind_leg")
    det = _scattered(model, rig, LOCUST, px, seed=2)
    assert _witness(model, rig, det, LOCUST)[3] is None


def test_the_fit_reports_alternative_deg_only_where_a_dof_is_undetermined():
    """Through ``fit_sequence``: the straight stick insect leg under a pixel of scatter is
    ambiguous (``alternative_deg`` >= 10 deg), the clearly seen locust leg is not."""
    for name, q, px, undetermined in (("stick_insect_front_leg", STICK_STRAIGHT, 1.0, True),
                                       ("locust_hind_leg", LOCUST, 0.3, False)):
        model, rig = _subject(name)
        images = [_scattered(model, rig, q, px, seed=s) for s in range(3)]
        result = fit_sequence(images, model=model, rig=rig, params=FitParams(), seed=0,
                              histograms=Histograms.uniform(model, prior_weight=100.0))
        degs = [f.alternative_deg(model.rotational) for f in result.fits]
        if undetermined:
            assert all(d >= UNDETERMINED_DEG for d in degs), (name, degs)
        else:
            assert all(math.isnan(d) for d in degs), (name, degs)


def _orthographic_rows(rotations: list[np.ndarray], markers: int) -> np.ndarray:
    """(2 V M, 3 M) Jacobian of M markers' projections in orthographic views (the first two
    rows of each rotation) by the markers' world positions, rows (view, marker, u/v)."""
    blocks = [np.kron(np.eye(markers), r[:2]) for r in rotations]
    return np.vstack(blocks)


def test_the_shared_inflation_is_the_variance_ratio_of_markers_scattered_in_3d():
    """Monte Carlo of the linearised fit: markers scattered in 3D and seen by three
    orthographic views; each DOF's variance against what the residual, read as independent
    scatter, predicts."""
    rng = np.random.default_rng(3)
    markers, D = 8, 6
    rotations = [np.linalg.qr(rng.normal(size=(3, 3)))[0] for _ in range(3)]
    B = _orthographic_rows(rotations, markers)
    J = B @ rng.normal(size=(3 * markers, D))  # projections move because the markers do
    C = np.linalg.inv(J.T @ J)
    y = rng.normal(size=(20000, 3 * markers)) @ B.T  # (draws, 2P)
    theta = y @ J @ C
    residual = y - theta @ J.T
    read = np.mean(np.sum(residual**2, axis=1)) / (J.shape[0] - D) * np.diag(C)
    measured = theta.var(axis=0) / read
    inflation = shared_scatter_inflation(J, C, B)
    assert inflation.min() > 1.5  # the independent reading is far too narrow here
    assert inflation == pytest.approx(measured, rel=0.05)


def test_the_residual_tells_3d_scatter_from_scatter_independent_in_each_view():
    """Six orthographic views of markers: a residual from markers scattered in 3D is read
    as 3D scatter (the inflation stays), one from scatter independent in every projection
    (a calibration's error, noise) as such (no inflation), and an even mix in between."""
    rng = np.random.default_rng(5)
    markers, D = 8, 6
    B = _orthographic_rows([np.linalg.qr(rng.normal(size=(3, 3)))[0] for _ in range(6)], markers)
    J = B @ rng.normal(size=(3 * markers, D))
    C = np.linalg.inv(J.T @ J)
    shared = B @ rng.normal(size=(200, 3 * markers)).T  # (2P, draws)
    independent = rng.normal(size=shared.shape) * np.sqrt(np.sum(B * B) / B.shape[0])
    share = {name: np.array([residual_shares(J, C, B, None, y)[1] for y in draws.T])
             for name, draws in (("3d", shared), ("independent", independent),
                                 ("mix", shared + independent))}
    assert share["3d"] == pytest.approx(1.0)
    assert np.mean(share["independent"]) < 0.1
    assert 0.2 < np.mean(share["mix"]) < 0.8
    full = shared_scatter_inflation(J, C, B)
    assert full.min() > 3
    assert shared_scatter_inflation(J, C, B, shared[:, 0]) == pytest.approx(full)
    assert np.median([shared_scatter_inflation(J, C, B, y).max() for y in independent.T]) < 1.5


def test_views_shifted_as_a_whole_are_read_by_their_own_covariance():
    """Six orthographic views whose images are each shifted as a whole (a calibration's
    error) by normal draws: the residual is read as shifts, and each DOF's inflation
    follows its variance under such shifts against what the residual read as independent
    scatter predicts (Monte Carlo): never much below it (a share of the shifts read as 3D
    scatter errs wide), far below reading it all as 3D scatter, under 1 for some DOF.
    With noise added, the shares split."""
    rng = np.random.default_rng(6)
    markers, D, V = 8, 6, 6
    B = _orthographic_rows([np.linalg.qr(rng.normal(size=(3, 3)))[0] for _ in range(V)], markers)
    J = B @ rng.normal(size=(3 * markers, D))
    C = np.linalg.inv(J.T @ J)
    T = np.kron(np.eye(V), np.kron(np.ones((markers, 1)), np.eye(2)))  # (2P, 2V), rows (view, marker, u/v)
    y = rng.normal(size=(20000, 2 * V)) @ T.T  # (draws, 2P)
    theta = y @ J @ C
    residual = y - theta @ J.T
    read = np.mean(np.sum(residual**2, axis=1)) / (J.shape[0] - D) * np.diag(C)
    measured = theta.var(axis=0) / read
    shares = np.array([residual_shares(J, C, B, T, r) for r in y[:200]])
    assert np.mean(shares[:, 2]) > 0.9
    inflation = np.mean([shared_scatter_inflation(J, C, B, r, T) for r in y[:200]], axis=0)
    assert np.all(inflation > 0.9 * measured)
    assert np.all(inflation < 0.5 * shared_scatter_inflation(J, C, B))
    assert measured.min() < 1 and inflation.min() < 1
    noisy = [residual_shares(J, C, B, T, r + rng.normal(size=r.shape)) for r in y[:200]]
    assert 0.2 < np.mean([n[0] for n in noisy]) < 0.9 and np.mean([n[2] for n in noisy]) > 0.1


def test_one_orthographic_view_reads_shared_scatter_as_independent():
    """A single orthographic view sees each marker's 3D scatter as independent scatter of
    its two image coordinates (depth unseen): no widening."""
    rng = np.random.default_rng(4)
    B = _orthographic_rows([np.eye(3)], 8)
    J = B @ rng.normal(size=(24, 6))
    assert shared_scatter_inflation(J, np.linalg.inv(J.T @ J), B) == pytest.approx(np.ones(6))


def test_markers_slid_in_3d_leave_no_fit_10_degrees_off_without_a_witness():
    """The biped's markers slid 4 px in 3D (as skin slides; every camera sees a slide alike)
    and its posture refined from the truth into the minimum the slid markers make: every fit
    more than 10 deg off the truth gets a witness. Read as independent scatter, the residual
    leaves some of them without one."""
    subject = load("biped", None)
    truth = subject.trajectory(30, np.random.default_rng(0))
    rng = np.random.default_rng(1)
    off, missed_independent = 0, 0
    for q in truth:
        fit, (shared, independent) = witnesses(subject, slid_detections(subject, q, 4.0, rng), q,
                                               FitParams())
        if angle_gaps(fit, q)[subject.model.rotational].max() <= UNDETERMINED_DEG:
            continue
        off += 1
        assert shared
        missed_independent += not independent
    assert off >= 10 and missed_independent >= 1


def test_a_calibration_a_pixel_off_leaves_a_well_placed_spider_without_a_witness():
    """The spider's exact projections fitted with its rig shifted 1 px in every view (a
    calibration's error, ``bench/imperfect.py``): the posture stays within a few degrees and
    no DOF is reported undetermined. The residual is the views' disagreement, not 3D
    scatter, and a leg's DOF is allowed the floor of the projections it moves, not of all
    the spider's: with either reading as before, every image got a 10 deg witness."""
    from bench.imperfect import calibrated_rig

    subject = load("spider")
    shifted = replace(subject, rig=calibrated_rig(subject.rig, 1.0, np.random.default_rng(1)))
    for q in subject.trajectory(4, np.random.default_rng(0)):
        det = Detections.from_views(list(subject.rig.project(subject.model.marker_positions(q))))
        fit, (found, _) = witnesses(shifted, det, q, FitParams())
        assert angle_gaps(fit, q)[subject.model.rotational].max() < 3.0
        assert not found


def test_the_scatter_is_never_above_the_plain_error():
    """``core.fit`` passes over an image whose plain Eq. 5 error would not widen the witness's
    tolerance without reading its scatter: that needs scatter <= plain error for any
    posture, with sliding skin, an unmodelled marker, hidden markers and views left empty."""
    subject = load("rat")
    model, rig = subject.model, subject.rig
    data = render_and_detect(subject, 12, soft=True, ghosts=0, rng=np.random.default_rng(3), occlusion=0.2)
    first = data.detections[0]
    dets = [*data.detections, Detections.from_views([first.view(0), [], first.view(2)])]  # a view empty
    truths = [*data.truth, data.truth[0]]
    off, rng = view_offsets(None, rig), np.random.default_rng(4)
    compared = 0
    for det, q in zip(dets, truths, strict=True):
        for spread in (0.0, 2.0, 20.0):  # at the truth, near it, far from it (markers off their blobs)
            p = np.clip(q + rng.normal(0, spread, q.shape), model.lower, model.upper)
            scatter = scatter_error(p, det, model, rig, off, 5.0, 8.0)
            assert scatter <= plain_error(p, det, model, rig, off, 5.0) * (1 + 1e-12)
            compared += 1
    assert compared == 39 and data.hidden is not None and data.hidden.any()


def test_a_short_trial_with_sliding_skin_reports_no_image_10_degrees_off_as_ok_unflagged():
    """20 biped images rendered as ``bench/animals.py --subject biped --soft-tissue --images 20``
    renders them (2 px RMS of slowly sliding skin, an unmodelled marker): the slid foot
    markers move the left ankle's minimum 10-12 deg off in nearly every image, and the
    residual, a pixel a projection, keeps half of them under the threshold. Each such image
    must give an alternative: with each DOF's interval at 99 % apiece, 10 of them were `ok`
    with none (the ankle's 10 deg step rose 1.4-2 one-DOF tolerances); with the image's 16
    intervals holding together, none is."""
    off_ok, unflagged = _off_and_ok("biped", 20)
    assert off_ok >= 5  # the case this test is about
    assert unflagged == 0


def test_a_free_fly_with_sliding_markers_reports_no_image_10_degrees_off_as_ok_unflagged():
    """12 images of the free fly (``bench/animals.py --subject freefly --soft-tissue``: six
    cameras, 2 px RMS of sliding markers, an unmodelled one): the thorax's roll and the
    short-coxa legs' adduction trade against each other, and the objective's minimum lies
    12-22 deg off the truth at about 0.9 px a projection, under the threshold. Its residual
    read as independent scatter stayed under the fixed floor, so the witness was never
    looked for and such images were `ok` with no alternative; read as the markers' 3D
    scatter (what the witness's tolerance is), it is looked for and found."""
    off_ok, unflagged = _off_and_ok("freefly", 12)
    assert off_ok >= 3  # the case this test is about
    assert unflagged == 0


def _off_and_ok(name: str, images: int) -> tuple[int, int]:
    """A bench subject's first ``images`` with sliding markers, rendered and fitted as
    ``bench/animals.py --subject name --soft-tissue`` does (seed 0): how many are more than
    ``UNDETERMINED_DEG`` off and ``ok``, and how many of those give no alternative."""
    subject = load(name)
    data = render_and_detect(subject, images, soft=True, ghosts=0, rng=np.random.default_rng(0))
    params, _ = fit_params(data)
    model = subject.model
    result = fit_sequence(data.detections, model=model, rig=subject.rig,
                          histograms=Histograms.uniform(model, prior_weight=100.0), params=params, seed=0)
    fitted = np.array([f.dofs for f in result.fits])
    off = np.abs(angle_errors(model, fitted, data.truth)[:, model.rotational]).max(axis=1) > UNDETERMINED_DEG
    ok = np.array([f.status is Status.OK for f in result.fits])
    flagged = np.array([math.isfinite(f.alternative_deg(model.rotational)) for f in result.fits])
    return int(np.count_nonzero(off & ok)), int(np.count_nonzero(off & ok & ~flagged))


def _hidden(model: KinematicModel, rig: Rig, q: np.ndarray, drop: dict[int, list[int]]) -> Detections:
    """Exact projections of ``q`` without the markers ``drop[view]`` (hidden from that view)."""
    proj = rig.project(model.marker_positions(q))
    return Detections.from_views([np.delete(p, drop.get(v, []), axis=0) for v, p in enumerate(proj)])


def test_a_hidden_marker_is_not_read_as_scatter():
    model, rig = _subject("locust_hind_leg")
    off = view_offsets(None, rig)
    det = _hidden(model, rig, LOCUST, {1: [2]})
    projections = rig.project(model.marker_positions(LOCUST))
    assert np.argwhere(hidden_projections(marker_errors(projections, det), 5.0)).tolist() == [[1, 2]]
    assert view_error(LOCUST, det, model=model, rig=rig) > 10.0  # charged its nearest other blob
    assert scatter_error(LOCUST, det, model, rig, off, 5.0, 8.0) == pytest.approx(0.0, abs=1e-9)
    # More than a quarter of the projections that far is a wrong fit, not hidden markers.
    many = _hidden(model, rig, LOCUST, {0: [2, 3], 1: [2]})
    assert not hidden_projections(marker_errors(projections, many), 5.0).any()
    assert scatter_error(LOCUST, many, model, rig, off, 5.0, 8.0) == pytest.approx(
        view_error(LOCUST, many, model=model, rig=rig))


def test_a_fused_blob_is_not_read_as_scatter():
    """Two markers imaged as one blob between them: each lies half their separation from it,
    which is no scatter about the model where the objective fuses them (closer than
    fusion_px), and is where it does not."""
    model, rig = _subject("locust_hind_leg")
    off = view_offsets(None, rig)
    proj = rig.project(model.marker_positions(LOCUST))
    gap = np.linalg.norm(proj[0][:, None] - proj[0][None], axis=2) + np.eye(4) * 1e9
    i, j = np.unravel_index(np.argmin(gap), gap.shape)
    merged = np.vstack([np.delete(proj[0], [i, j], axis=0), (proj[0][i] + proj[0][j]) / 2])
    det = Detections.from_views([merged, proj[1]])
    assert scatter_error(LOCUST, det, model, rig, off, 100.0, gap[i, j] + 1.0) == pytest.approx(0.0, abs=1e-9)
    assert scatter_error(LOCUST, det, model, rig, off, 100.0, 0.0) == pytest.approx(
        view_error(LOCUST, det, model=model, rig=rig)) and gap[i, j] > 1.0


def test_a_clean_image_with_a_hidden_marker_is_not_undetermined():
    """Noise-free locust images with one marker hidden from one camera fit exactly; read as
    scatter, the hidden marker's charge made each of them look like sliding skin, with a
    DOF 10 deg away 'within' the tolerance."""
    model, rig = _subject("locust_hind_leg")
    images = [_hidden(model, rig, LOCUST, {v: [m]}) for v, m in ((0, 0), (1, 0), (1, 2))]
    result = fit_sequence(images, model=model, rig=rig, params=FitParams(), seed=0,
                          histograms=Histograms.uniform(model, prior_weight=100.0))
    for fit in result.fits:
        assert angle_gaps(fit.dofs, LOCUST).max() < 0.01
        assert math.isnan(fit.alternative_deg(model.rotational))


def test_a_marker_no_camera_sees_or_one_of_three_is_unseen():
    """Distances (V, M) px to the nearest blob: hidden beyond the 5 px penalty. Marker 1 is
    hidden from every view; marker 2 from all but one of four; marker 3 from one. With two
    views, a marker one of them sees is not unseen (the paper's locust is filmed so)."""
    d = np.full((4, 10), 0.2)  # ten markers: a quarter of the projections far is a wrong fit
    d[:, 1] = 30.0
    d[1:, 2] = 30.0
    d[0, 3] = 30.0
    assert np.flatnonzero(unseen_markers(d, 5.0)).tolist() == [1, 2]
    assert np.flatnonzero(unseen_markers(d[:2], 5.0)).tolist() == [1]
    d[2:] = np.nan  # views without blobs do not count: two views left
    assert np.flatnonzero(unseen_markers(d, 5.0)).tolist() == [1]


def test_a_marker_on_another_markers_blob_or_only_on_fused_blobs_is_unseen():
    """Distances (V, M) px to the nearest blob, beyond the 5 px penalty hidden. Six views:
    marker 0 is hidden from four and 3 px from another marker's blob in two (borrowed, as a
    finger by its wrist marker), so no view sees it. Two views: marker 1 is hidden from one
    and fused in the other, on no blob of its own. Marker 2 is fused in every view, some of
    them far from the merged blob (big markers whose joints touch): not hidden at all.
    Marker 3 is fused in one of three views, on its own blob in another: seen in both."""
    d = np.full((6, 10), 0.2)
    d[[0, 2, 3, 5], 0] = 20.0
    d[[1, 4], 0] = 3.0
    borrowed, fused = np.zeros((6, 10), bool), np.zeros((6, 10), bool)
    borrowed[[1, 4], 0] = True
    assert np.flatnonzero(unseen_markers(d, 5.0, borrowed, fused)).tolist() == [0]
    assert not unseen_markers(d, 5.0).any()  # read without the blobs' owners: seen twice

    d = np.full((2, 10), 0.2)
    d[0, 1], fused = 7.6, np.zeros((2, 10), bool)
    fused[1, 1] = True
    assert np.flatnonzero(unseen_markers(d, 5.0, None, fused)).tolist() == [1]
    assert not unseen_markers(d, 5.0).any()

    d, fused = np.full((3, 10), 0.2), np.zeros((3, 10), bool)
    d[[0, 2], 2] = 7.0
    fused[:, 2] = True
    d[2, 3], fused[0, 3] = 30.0, True
    assert not unseen_markers(d, 5.0, None, fused).any()


def test_markers_of_two_joints_at_one_point_in_every_view_are_crossed():
    """Three markers, two views with blobs and one without; 4 px fusion (2 px markers).
    Markers 0 and 2 (on two joints) lie on one blob 0.5 px apart in both views with blobs:
    one point in space, crossed. Not crossed: markers of one joint so; two joints' markers
    1.5 px apart in one view (fused, but two markers can lie so); with one view with blobs."""
    projected = np.array([[[10.0, 10.0], [40.0, 10.0], [10.5, 10.0]],
                          [[20.0, 30.0], [60.0, 30.0], [20.0, 30.5]],
                          [[0.0, 0.0], [5.0, 5.0], [9.0, 9.0]]])
    det = Detections.from_views([[[10.2, 10.0], [40.0, 10.0]], [[20.0, 30.2], [60.0, 30.0]], []])
    joints = np.eye(3, dtype=bool)
    assert np.flatnonzero(crossed_markers(projected, det, 4.0, joints)).tolist() == [0, 2]
    assert not crossed_markers(projected, det, 4.0, np.ones((3, 3), bool)).any()
    apart = projected.copy()
    apart[1, 2] = [21.5, 30.0]
    assert not crossed_markers(apart, det, 4.0, joints).any()
    one_view = Detections.from_views([[[10.2, 10.0], [40.0, 10.0]], [], []])
    assert not crossed_markers(projected, one_view, 4.0, joints).any()


def test_a_crossed_marker_is_unseen_without_a_hidden_projection():
    """Distances (V, M) px, none beyond the 5 px penalty: marker 0 is fused in every view.
    Fused with a marker near it it is not hidden; crossed with a marker on another joint
    (at one point with it in every view), no view sees it."""
    d = np.full((3, 10), 0.5)
    fused = np.zeros((3, 10), bool)
    fused[:, 0] = True
    crossed = np.zeros(10, bool)
    assert not unseen_markers(d, 5.0, None, fused, crossed).any()
    crossed[0] = True
    assert np.flatnonzero(unseen_markers(d, 5.0, None, fused, crossed)).tolist() == [0]


def test_markers_on_one_joint_are_rigid():
    """The thorax's three markers are rigid with each other (no posture moves them apart); a
    leg's markers on its several joints are not all, and none is with the thorax's."""
    model = insect(legs=2)
    rigid = rigid_markers(model)
    names = [m.name for m in model.markers]
    leg0 = [i for i, n in enumerate(names) if n.startswith("leg0")]
    thorax = [i for i, n in enumerate(names) if n.startswith("T")]
    assert len(thorax) == 3 and rigid[np.ix_(thorax, thorax)].all()
    assert not rigid[np.ix_(leg0, thorax)].any()
    assert not rigid[np.ix_(leg0, leg0)].all()
    assert (rigid == rigid.T).all()


def test_a_claw_hidden_from_both_cameras_is_never_ok_far_off_without_an_alternative():
    """The benchmark stick insect with 10 % of its markers hidden from both cameras at once
    (seed 2). At image 20 the claw is hidden; the fit bends the leg so that the claw lands
    on the coxa's blob in one view, γ 111° off. Before, that view counted as seeing the
    claw, and the image was ``ok`` with an alternative as far off (none given for γ): now
    the claw is unseen and its DOFs' witness stands."""
    subject = load("stick")
    data = render_and_detect(subject, 60, soft=False, ghosts=2, rng=np.random.default_rng(2),
                             occlusion=0.1, everywhere=True)
    params = fit_params(data)[0]
    result = fit_sequence(data.detections, model=subject.model, rig=subject.rig, params=params, seed=2,
                          histograms=Histograms.uniform(subject.model, prior_weight=100.0))
    rot = subject.model.rotational
    fitted = np.array([fit.dofs for fit in result.fits])
    off = np.abs(angle_errors(subject.model, fitted, data.truth)[:, rot]).max(axis=1)
    assert off[20] > 10.0 and data.hidden[20, :, 3].all()
    for fit, image_off in zip(result.fits, off, strict=True):
        assert image_off <= 10.0 or fit.status is not Status.OK or math.isfinite(fit.alternative_deg(rot))


def test_a_leg_folded_onto_the_other_is_never_ok_far_off_without_an_alternative():
    """The benchmark rat with 20 % of its markers hidden from all three cameras at once
    (seed 0), images 16-17. At 17 the right ankle and toe are hidden; the fit folds the right
    leg onto the left, the two ankles and the two toes fused in every view, hip flexion 35°
    off. No projection of theirs looked hidden, so nothing said they were unseen, and the
    image was ``ok`` with no alternative: now they are crossed, and their DOFs' witness
    stands."""
    subject = load("rat")
    data = render_and_detect(subject, 18, soft=False, ghosts=2, rng=np.random.default_rng(0),
                             occlusion=0.2, everywhere=True)
    result = fit_sequence(data.detections[16:], model=subject.model, rig=subject.rig,
                          params=fit_params(data)[0], seed=0,
                          histograms=Histograms.uniform(subject.model, prior_weight=100.0))
    rot = subject.model.rotational
    fit = result.fits[-1]
    names = [m.name for m in subject.model.markers]
    assert data.hidden[17][:, [names.index("R_ankle"), names.index("R_toe")]].all()
    assert np.abs(angle_errors(subject.model, fit.dofs[None], data.truth[17:])[0, rot]).max() > 10.0
    assert fit.status is not Status.OK or math.isfinite(fit.alternative_deg(rot))


def test_a_claw_no_camera_sees_leaves_its_dof_undetermined_in_a_clean_image():
    """Two legs, three cameras, noise-free; leg 0's claw hidden from every camera. The image
    is clean everywhere else, so the residual alone would not search for a witness, and the
    knee (which only the claw places) could stand anywhere, ``ok`` with no alternative. The
    claw is unseen: left out, the knee is found undetermined, a witness 10 deg or more away."""
    model, rig = insect(legs=2), ring_rig(3)
    truth = movement(model, 2, seed=1)[1]
    leg = model.tree.branches[0]
    claw = int(leg.markers[-1])
    proj = rig.project(model.marker_positions(truth)) + 0.05
    det = Detections.from_views([np.delete(p, claw, axis=0) for p in proj])
    error = view_error(truth, det, model=model, rig=rig)
    witness = _undetermined_witness(Candidate(truth, error, error), det, model, rig, FitParams(), None)
    assert witness is not None
    gaps = angle_gaps(witness.dofs, truth)
    assert gaps[model.dof_names.index("leg0_knee")] >= UNDETERMINED_DEG
    assert np.delete(gaps, leg.dofs).max() < 1e-9  # the other leg stays
    clean = detections(model, rig, truth[None])[0]
    assert _undetermined_witness(Candidate(truth, 0.0, 0.0), clean, model, rig, FitParams(), None) is None


def test_a_fused_blob_and_a_hidden_marker_are_no_residual():
    """The residual the shares are read from: each projection's offset from its nearest
    blob, none for two markers sharing one blob (fused: its centroid lies between them) or
    for a marker farther than the penalty from every blob (hidden)."""
    from core.undetermined import _residual_vectors

    projected = np.array([[[10.0, 10.0], [14.0, 10.0], [50.0, 50.0], [90.0, 90.0]]])
    det = Detections.from_views([[[12.0, 10.0], [50.5, 49.0], [70.0, 90.0]]])
    residual = _residual_vectors(projected, det, np.ones((1, 4), dtype=bool), 5.0, 8.0)
    assert residual.tolist() == [0.0, 0.0, 0.0, 0.0, -0.5, 1.0, 0.0, 0.0]


def test_noise_free_mouse_images_are_ambiguous_only_with_a_distinct_alternative():
    """The mouse (a camera and a mirror, fused toes): its depth flips refined back to within
    a few degrees of the fit made images ambiguous 1.8-4.5 deg apart. Every alternative_deg
    given is now above DISTINCT_DEG, and every image is within 5 deg of the truth."""
    from core.ambiguity import DISTINCT_DEG

    subject = load("mouse")
    data = render_and_detect(subject, 12, soft=False, ghosts=2, rng=np.random.default_rng(0))
    params, _ = fit_params(data)
    prior = Histograms.uniform(subject.model, prior_weight=100.0)
    result = fit_sequence(data.detections, model=subject.model, rig=subject.rig, histograms=prior,
                          params=params, seed=0)
    rot = subject.model.rotational
    fitted = np.array([f.dofs for f in result.fits])
    assert np.abs(angle_errors(subject.model, fitted, data.truth)[:, rot]).max() < 5.0
    given = [f.alternative_deg(rot) for f in result.fits if math.isfinite(f.alternative_deg(rot))]
    assert all(deg > DISTINCT_DEG for deg in given), given
    near = [f for f in result.fits if any(angle_gaps(a.dofs, f.dofs)[rot].max() <= DISTINCT_DEG
                                          for a in f.alternatives)]
    assert near  # such flips are still there, for the choice by continuity


def test_a_branch_two_views_barely_place_is_not_far_off_unflagged():
    """``bench/random_trees.py --cameras 2``, seed 4, model 4 (a fixed root, four branches, 29
    DOFs; clean images): in images 3-6 one branch turns 10-13° from the truth through a
    valley within the tolerance (the fit scores 1.21-1.39 px, the truth refined 1.25-1.33).
    The residual did not turn the witness search on, and refined on that branch alone a
    step along the valley stayed 2 px above it: its markers fuse with another branch's.
    With two views the search runs, and the whole model follows: every image more than 10°
    off has an alternative."""
    rng = np.random.default_rng([4, 4])
    model = random_model(rng, 2)
    subject = filmed(model, 2, 100.0)
    data = render_and_detect(subject, 8, soft=False, ghosts=2, rng=rng)
    result, _ = bench_fit(subject, data, seed=4, jobs=1)
    rot = model.rotational
    fitted = np.array([f.dofs for f in result.fits])
    worst = np.abs(angle_errors(model, fitted, data.truth)[:, rot]).max(axis=1)
    assert (worst > FAR_OFF_DEG).sum() >= 3
    assert not (bad := far_off_unflagged(worst, *fit_flags(result, rot))).size, bad


def test_a_hidden_marker_on_a_marker_of_its_own_chain_is_unseen():
    """``bench/random_trees.py --cameras 2 --occlusion 0.1``, seed 6, model 7: one branch on
    a free root, a single chain of 10 DOFs. In image 30 the branch's first marker, hidden from
    both cameras, is fitted onto a root marker's blob, 0.9 and 0.2 px from that marker in the
    two views: the branch's roll is 17° off, ``ok``. Two markers of one chain were never
    crossed, so nothing was unseen and no witness was looked for. Two markers on two joints
    at one point in both views are crossed: the roll's witness is found."""
    rng = np.random.default_rng([6, 7])
    model = random_model(rng, 2)
    assert model.tree is None
    subject = filmed(model, 2, 100.0)
    data = render_and_detect(subject, 40, soft=False, ghosts=2, rng=rng, occlusion=0.1)
    result, _ = bench_fit(subject, data, seed=6, jobs=1)
    rot = model.rotational
    fitted = np.array([f.dofs for f in result.fits])
    worst = np.abs(angle_errors(model, fitted, data.truth)[:, rot]).max(axis=1)
    ok, flagged = fit_flags(result, rot)
    assert ok[30] and worst[30] > FAR_OFF_DEG
    assert not (bad := far_off_unflagged(worst, ok, flagged)).size, bad
