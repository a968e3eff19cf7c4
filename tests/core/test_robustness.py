"""Robustness of the whole chain (render → detect → fit) with asserted, measured bounds.

Every test renders frames with ``core.synth.render_frames``, detects them with
``core.detect.detect``, fits them with ``core.sequence.fit_sequence`` with the default
``FitParams`` apart from ``fusion_px = 8`` (twice the 4 px markers' diameter, as
``bench/accuracy.py``), and
compares to the truth; interlaced footage and frames without markers go through files
and the CLI (``mocap synth``, ``mocap fit [--deinterlace]``, which detects fields with
``core.fields.detect_fields``). Each docstring says what was measured (seeds, numbers)
and why the bound; measurements were taken with this module's helpers (sweeps over more
seeds with scripts doing the same) on a 2-core x86-64 machine. Results are deterministic
for a seed; every bound leaves margin and can fail.

Tests marked ``xfail(strict=True)`` demonstrate a defect found here: frames that went
wrong but are reported ``ok``. They assert what should hold, and fail today. Three more
were found with the first version of this module and are fixed (the merged pairs, the
blob left unexplained, the local minimum under the threshold): their tests now pass.
"""

from __future__ import annotations

import copy
import csv
import functools
import json

import numpy as np
import pytest
from typer.testing import CliRunner

from cli.app import app
from core.benchmark import single_view
from core.detect import detect
from core.error import Detections
from core.examples import EXAMPLES
from core.fit import FitParams, Status
from core.histogram import Histograms
from core.model import KinematicModel
from core.results import read_angles_csv
from core.rig import Rig
from core.sequence import SequenceResult, fit_sequence
from core.synth import natural_movements, read_truth_csv, render_frames, write_video

LOCUST, STICK_INSECT = "locust_hind_leg", "stick_insect_front_leg"
MARKER_PX = 4.0
PARAMS = FitParams(fusion_px=2 * MARKER_PX)  # defaults otherwise: threshold 10 px, 5 attempts
SIDE, TOP = 0, 1  # the locust rig's views
WRONG_DEG = 2.0  # a frame more than this off in any DOF has gone wrong (targets: 0.5° RMSE)


# ---- helpers ---------------------------------------------------------------------------------


@functools.cache
def _example(name: str) -> tuple[KinematicModel, Rig]:
    return (KinematicModel.from_xml(EXAMPLES / name / "model.xml"),
            Rig.from_json(EXAMPLES / name / "rig.json"))


def _movement(name: str, n: int, seed: int, n_sequences: int = 1) -> tuple[np.ndarray, np.random.Generator]:
    """Natural movement of ``n`` samples, and the generator that goes on to render it."""
    model, rig = _example(name)
    rng = np.random.default_rng(seed)
    return natural_movements(model, rig, n, rng=rng, n_sequences=n_sequences), rng


def _detections(name: str, truth: np.ndarray, rng: np.random.Generator, *,
                rig: Rig | None = None, **render: object) -> list[Detections]:
    """Render ``truth`` (through ``rig``, the example's own by default) and detect every frame."""
    model, own = _example(name)
    frames = render_frames(model, rig or own, truth, rng=rng, marker_diameter_px=MARKER_PX, **render)
    return [detect([frame], rig=own) for frame in frames]


def _fit(name: str, detections: list[Detections], seed: int, *, rig: Rig | None = None,
         params: FitParams = PARAMS) -> SequenceResult:
    model, own = _example(name)
    return fit_sequence(detections, model=model, rig=rig or own, histograms=Histograms.uniform(model),
                        params=params, seed=seed)


def _abs_errors(result: SequenceResult, truth: np.ndarray) -> np.ndarray:
    """(T, D) absolute error of every fitted DOF, degrees (NaN where nothing was fitted)."""
    return np.abs(np.array([f.dofs for f in result.fits]) - truth)


def _rmse(errors: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean(errors**2, axis=0))


def _errors_px(result: SequenceResult) -> np.ndarray:
    return np.array([f.error for f in result.fits])


def _statuses(result: SequenceResult) -> list[Status]:
    return [f.status for f in result.fits]


def _wrong_but_ok(result: SequenceResult, errors: np.ndarray) -> list[tuple[int, float, float]]:
    """(sample, worst DOF error °, error_px) of frames more than WRONG_DEG off yet reported ok."""
    return [(f.sample, round(float(e.max()), 2), round(f.error, 2))
            for f, e in zip(result.fits, errors, strict=True)
            if f.status is Status.OK and e.max() > WRONG_DEG]


def _top_view_pair_postures(seed: int, lo_px: float, hi_px: float, per_pair: int = 8) -> np.ndarray:
    """Locust postures where the tarsus marker M3 projects ``lo_px``..``hi_px`` from M0, M1 or M2
    in the top view (``per_pair`` each, in that order), every marker 8 px inside its roi.

    In the locust rig only the top view ever brings two markers that close: the tarsus
    seen over the coxa, or the tibia seen end-on (pairs with M3).
    """
    model, rig = _example(LOCUST)
    rng = np.random.default_rng(seed)
    q = rng.uniform(model.lower + 3.0, model.upper - 3.0, (100_000, len(model.dofs)))
    proj = rig.project(model.marker_positions(q))  # (N, V, M, 2)
    rois = np.array([v.roi for v in rig.views], dtype=np.float64)  # (V, 4): x, y, w, h
    lo, hi = rois[:, None, :2] + 8.0, rois[:, None, :2] + rois[:, None, 2:] - 8.0
    inside = np.all((proj >= lo) & (proj <= hi), axis=(1, 2, 3))
    chosen = []
    for other in (0, 1, 2):
        d = np.linalg.norm(proj[:, TOP, 3] - proj[:, TOP, other], axis=1)
        chosen.append(q[np.flatnonzero(inside & (d >= lo_px) & (d < hi_px))[:per_pair]])
    return np.concatenate(chosen)


def _blobs(detections: list[Detections], view: int) -> np.ndarray:
    return np.array([d.counts[view] for d in detections])


def _moved_rig(rig: Rig, shift_px: tuple[float, float] = (0.0, 0.0), zoom: float = 1.0) -> Rig:
    """The rig with every affine view zoomed about the world origin and shifted, in pixels."""
    doc = copy.deepcopy(rig.to_dict())  # to_dict shares the views' projection dicts
    for view in doc["views"]:
        m = np.array(view["projection"]["matrix"], dtype=np.float64)
        m[:, :3] *= zoom
        m[:, 3] += shift_px
        view["projection"]["matrix"] = m.tolist()
    return Rig.from_dict(doc)


def _swapped_rig(rig: Rig) -> Rig:
    """The locust rig with the side and top cameras exchanged (each drawn in the other's roi)."""
    doc = copy.deepcopy(rig.to_dict())
    side, top = (np.array(v["projection"]["matrix"], dtype=np.float64) for v in doc["views"])
    side[1, 3] += 288.0  # the side camera's image, drawn in the top roi
    top[1, 3] -= 288.0
    doc["views"][SIDE]["projection"]["matrix"] = top.tolist()
    doc["views"][TOP]["projection"]["matrix"] = side.tolist()
    return Rig.from_dict(doc)


def _cli(*args: object):
    return CliRunner().invoke(app, [str(a) for a in args])


# ---- 1. ghost markers in every frame ---------------------------------------------------------


@pytest.mark.parametrize("ghosts", [2, 4])
def test_ghost_markers_in_every_frame_keep_the_fit_within_bounds(ghosts):
    """2 or 4 ghost discs per view in every frame: locust, 6 seeds × 30 frames, pooled.

    Measured on these inputs: every frame ok; pooled RMSE ≤ 0.33° (β, 2 ghosts), ≤ 0.13°
    (4 ghosts); worst frame 4.3° (2 ghosts) / 1.7° (4 ghosts); 1.1 % / 0.6 % of frames more
    than 1° off; median error_px 0.07 px; frames with error_px < 0.5 px within 0.11°.
    The worst frames are those where a ghost lands on a marker and the detector merges
    them, shifting that blob's centroid by up to ~2 px (the fit follows the data), and,
    rarely, a ghost that holds SA in a local minimum (seed 14: 5.7° off at 7.7 px; see
    the last test); error_px of frames > 0.5° off: 0.7–7.8 px. Over 30 seeds (1800
    frames): all ok, worst 8.9°, 1 % of frames > 1°, frames with error_px < 0.5 px
    within 0.15°.
    Bounds: pooled RMSE < 1°, every frame < 10°, ≤ 5 % of frames > 1°, frames with
    error_px < 0.5 px within 0.3°, median error_px < 0.15 px, all ok.
    """
    errors, errors_px, statuses, blobs = [], [], [], []
    for seed in range(6):
        truth, rng = _movement(LOCUST, 30, seed)
        detections = _detections(LOCUST, truth, rng, ghosts_per_view=ghosts)
        result = _fit(LOCUST, detections, seed)
        errors.append(_abs_errors(result, truth))
        errors_px.append(_errors_px(result))
        statuses += _statuses(result)
        blobs += [d.counts for d in detections]
    err, px = np.concatenate(errors), np.concatenate(errors_px)
    assert np.median(blobs, axis=0).tolist() == [4 + ghosts] * 2  # the ghosts are detected
    assert all(s is Status.OK for s in statuses)
    assert np.all(_rmse(err) < 1.0), _rmse(err).round(3)
    assert err.max() < 10.0
    assert np.mean(err.max(axis=1) > 1.0) <= 0.05
    assert err[px < 0.5].max() < 0.3
    assert np.median(px) < 0.15


def test_ghost_markers_on_the_stick_insect_keep_the_clean_footage_bounds():
    """3 ghosts per view on the stick insect (6 DOFs), 4 seeds × 30 frames, pooled.

    Measured: all ok; median error per DOF ≤ 0.02°; 5.0 % of frames more than 2° off
    (the paper's Fig. 9 ambiguity, where femur and tibia markers image over the body
    markers: two postures explain the blobs equally well; without ghosts, 8 seeds: 2.5 %);
    median error_px 0.07 px. Bounds: median < 0.1° per DOF, ≤ 10 % of frames > 2° off,
    median error_px < 0.15 px, all ok.
    """
    errors, errors_px, statuses = [], [], []
    for seed in range(4):
        truth, rng = _movement(STICK_INSECT, 30, seed)
        result = _fit(STICK_INSECT, _detections(STICK_INSECT, truth, rng, ghosts_per_view=3), seed)
        errors.append(_abs_errors(result, truth))
        errors_px.append(_errors_px(result))
        statuses += _statuses(result)
    err = np.concatenate(errors)
    assert all(s is Status.OK for s in statuses)
    assert np.all(np.median(err, axis=0) < 0.1), np.median(err, axis=0).round(3)
    assert np.mean(err.max(axis=1) > 2.0) <= 0.10
    assert np.median(np.concatenate(errors_px)) < 0.15


# ---- 2. two markers fused into one blob ------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_overlapping_markers_are_fitted_as_one_blob(seed):
    """24 postures whose top view shows the tarsus marker less than one marker diameter
    (4 px) from the coxa, trochanter or femur-tibia marker: the two discs overlap and are
    detected as one blob (3 blobs in the top view).

    Measured (seeds 0–2): all ok, worst DOF 0.09°, 0.09°, 0.14°; error_px ≤ 4.02 px (plain
    Eq. 5 charges each fused marker its distance to the blob's centroid). With other
    rendering streams, 10 seeds × 24 frames in each of the 0–2, 2–3, 3–4 px bands: worst
    0.31°. With the paper's plain Eq. 5 (fusion_px = 0) the same frames
    are 2.2°, 2.4°, 3.7° off at worst. Bounds: every frame < 1° and ok, error_px < 5 px,
    and plain Eq. 5 > 1° off somewhere (so that the postures are fusions that matter).
    """
    truth = _top_view_pair_postures(seed, 0.0, MARKER_PX)
    detections = _detections(LOCUST, truth, np.random.default_rng(seed))
    assert len(truth) == 24 and np.all(_blobs(detections, TOP) == 3) and np.all(_blobs(detections, SIDE) == 4)
    result = _fit(LOCUST, detections, seed)
    err = _abs_errors(result, truth)
    assert all(s is Status.OK for s in _statuses(result))
    assert err.max() < 1.0, err.max(axis=0).round(3)
    assert _errors_px(result).max() < 5.0
    plain = _abs_errors(_fit(LOCUST, detections, seed, params=FitParams()), truth)
    assert plain.max() > 1.0


def test_markers_the_detector_merges_just_beyond_fusion_px_are_fitted_as_one_blob():
    """Top-view pairs 4–5 px apart (discs just apart, one blob to the detector): the frames
    with 3 blobs in the top view meet the bound of overlapping markers (< 1°).

    Found with fusion_px = 4 and a fixed reading (fused below it, apart beyond): 13 of 40
    merged frames > 1°, worst 2.4°, all ok (also frames 414, 415, 583, the three worst
    of the 668-frame benchmark); fusion_px = 5 then broke pairs the detector does not
    merge (9.8°). Now every view is read both ways (``core._kernels.blob_error``) with
    fusion_px = 2 diameters: measured (seeds 0, 1) 40 merged frames, worst 0.11°.
    """
    off = []
    for seed in (0, 1):
        truth = _top_view_pair_postures(seed, MARKER_PX, 5.0)
        detections = _detections(LOCUST, truth, np.random.default_rng(seed))
        err = _abs_errors(_fit(LOCUST, detections, seed), truth)
        merged = _blobs(detections, TOP) == 3
        off += [(seed, int(t), round(float(err[t].max()), 2)) for t in np.flatnonzero(merged)
                if err[t].max() >= 1.0]
    assert off == []


def test_two_separate_blobs_close_together_are_not_explained_by_one():
    """Top-view pairs 5–6 px apart that the detector sees as two blobs: no frame is more
    than 2° off yet reported ok.

    Found over 10 seeds (228 such frames): 2 frames (seeds 4 and 7, the two fitted here)
    put both markers on one blob and left the other unexplained, 4.24° and 2.21° off,
    ok; Eq. 5 does not charge an unexplained detection. Now one next to markers that
    share a blob is charged (the paper's Fig. 9): measured worst 0.15° on these seeds.
    """
    wrong = []
    for seed in (4, 7):
        truth = _top_view_pair_postures(seed, 5.0, 6.0)
        detections = _detections(LOCUST, truth, np.random.default_rng(seed))
        result = _fit(LOCUST, detections, seed)
        separate = _blobs(detections, TOP) == 4
        wrong += [(seed, *w) for w in _wrong_but_ok(result, _abs_errors(result, truth))
                  if separate[w[0]]]
    assert wrong == []


# ---- 3. a marker missing from one view for a few frames --------------------------------------


GAP = np.arange(10, 16)  # six consecutive frames of 30


@pytest.mark.parametrize(
    ("view", "marker", "outcome"),
    [(SIDE, 0, "accurate"), (TOP, 0, "accurate"), (TOP, 1, "accurate"),
     (SIDE, 2, "flagged"), (TOP, 2, "flagged"), (SIDE, 3, "flagged"),
     (TOP, 3, "flagged")],
)
def test_a_marker_missing_from_one_view_is_survived_or_flagged(view, marker, outcome):
    """Marker ``marker`` not drawn in ``view`` for frames 10–15 of 30; seeds 0–2.

    Eq. 5 charges the missing marker its distance to the nearest other blob of that view;
    the fit's objective instead lets each view lose one marker (charged 5 px) once the
    first run stays above ε, and refits without it. Measured, seeds 0–2: near the root
    (side M0, top M0, top M1) gap frames within 0.11°, flagged over_threshold in 13, 18
    and 18 of 18 frames (error_px 8.8–13.1: the missing marker's ~13 px); missing M2 or
    M3 (either view), gap frames within 0.27° and all 18 flagged (error_px 27–77, the
    distance Eq. 5 charges for it) after 5 attempts. Frames outside the gap: ok, within
    0.10°. (Top M3 used to bend the leg 18–41° in 8 of 18 frames, one reported ok: SA
    stopped restarting in that basin; ``core._kernels.fit_attempt`` now restarts on.)
    Bounds: every gap frame within 1° or over_threshold; "accurate": every gap frame
    within 1°; "flagged": every gap frame over_threshold, error_px > 10 px, 5 attempts or
    settled (a re-analysis ended in the kept minimum, ``core.fit.reanalyse_image``);
    frames outside the gap ok and within 0.3°. Missing M1 in the side view: see below.
    """
    rest = np.setdiff1d(np.arange(30), GAP)
    for seed in range(3):
        truth, rng = _movement(LOCUST, 30, seed)
        drop = np.zeros((30, 2, 4), dtype=bool)
        drop[GAP, view, marker] = True
        result = _fit(LOCUST, _detections(LOCUST, truth, rng, drop=drop), seed)
        err = _abs_errors(result, truth).max(axis=1)
        fits = result.fits
        assert all(fits[t].status is Status.OK for t in rest) and err[rest].max() < 0.3, seed
        assert all(err[t] < 1.0 or fits[t].status is Status.OVER_THRESHOLD for t in GAP), seed
        if outcome == "accurate":
            assert err[GAP].max() < 1.0, (seed, err[GAP].round(2))
        else:
            assert all(fits[t].status is Status.OVER_THRESHOLD and fits[t].error > 10.0
                       and (fits[t].attempts == PARAMS.max_attempts or fits[t].settled)
                       for t in GAP), seed


def test_a_missing_trochanter_marker_in_the_side_view_is_flagged_when_the_fit_goes_wrong():
    """As above for M1 in the side view: no gap frame may be > 2° off and ok.

    M1's distance to the nearest other blob (M0, 6.4–13 px) is below the error threshold,
    so a fit leaning towards it could pass as ok. Measured over seeds 0–9: 46 of 60 gap
    frames over_threshold, the 14 ok within 0.70°. (Before the lost-marker refit and the
    restarts that go on while the best costs a lost marker: 9 ok frames 4.0–8.1° off, all
    in seeds 2 and 9, the two fitted here.)
    """
    wrong = []
    for seed in (2, 9):
        truth, rng = _movement(LOCUST, 30, seed)
        drop = np.zeros((30, 2, 4), dtype=bool)
        drop[GAP, SIDE, 1] = True
        result = _fit(LOCUST, _detections(LOCUST, truth, rng, drop=drop), seed)
        wrong += [(seed, *w) for w in _wrong_but_ok(result, _abs_errors(result, truth))]
    assert wrong == []


# ---- 4. concatenated sequences with jumps ----------------------------------------------------


def test_no_error_spike_after_a_jump_between_concatenated_sequences():
    """60 frames = 4 concatenated sequences of 15 (3 jumps), 5 seeds: frames two either side
    of every jump.

    Every image is fitted on its own, so a jump of 42–117° (measured, largest DOF change
    between the last frame of a sequence and the first of the next) must not show. Measured:
    worst DOF error within ±2 frames of the 15 jumps 0.12° (over 15 seeds, 45 jumps: 0.20°),
    all ok. Bounds: every jump ≥ 20° in some DOF (so that it is one), every frame within
    ±2 of it ok and within 1°.
    """
    sizes = [len(a) for a in np.array_split(np.arange(60), 4)]
    starts = np.cumsum(sizes)[:-1]
    for seed in range(5):
        truth, rng = _movement(LOCUST, 60, seed, n_sequences=4)
        result = _fit(LOCUST, _detections(LOCUST, truth, rng), seed)
        err = _abs_errors(result, truth).max(axis=1)
        for s in starts:
            assert np.abs(truth[s] - truth[s - 1]).max() >= 20.0, (seed, s)
            around = range(s - 2, s + 3)
            assert all(result.fits[t].status is Status.OK for t in around), (seed, s)
            assert err[s - 2 : s + 3].max() < 1.0, (seed, s, err[s - 2 : s + 3].round(2))


# ---- 5. single-view rigs ---------------------------------------------------------------------


def _single_view_fit(view: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[Status]]:
    """Locust, one view only, 3 seeds × 40 frames (2 sequences): (truth, fitted, error_px,
    statuses), pooled."""
    _, rig = _example(LOCUST)
    truths, fitted, px, statuses = [], [], [], []
    for seed in range(3):
        truth, rng = _movement(LOCUST, 40, seed, n_sequences=2)
        one, detections = single_view(rig, _detections(LOCUST, truth, rng), view)
        result = _fit(LOCUST, detections, seed, rig=one)
        truths.append(truth)
        fitted.append(np.array([f.dofs for f in result.fits]))
        px.append(_errors_px(result))
        statuses += _statuses(result)
    return np.concatenate(truths), np.concatenate(fitted), np.concatenate(px), statuses


def test_side_view_alone_recovers_the_leg_plane_and_phi_psi_up_to_the_mirror():
    """Side view only: it cannot see depth (z), so the leg and its mirror image through the
    view's plane (φ ↔ 360° − φ, ψ ↔ −ψ, α β γ unchanged) image identically for φ in
    140..220°, and which one the fit reports is close to a coin toss (measured raw φ, ψ
    errors up to 71°). Per frame, the nearer of the fit and its mirror is compared.

    Measured (3 seeds, 120 frames): α, β, γ RMSE 0.05°, 0.05°, 0.09°, worst 0.84° (γ);
    φ, ψ up to the mirror RMSE 0.03°, 0.26°, worst 2.5° (ψ); error_px ≤ 0.04 px, all ok.
    Over 10 seeds one sequence (seed 9) has near-ambiguous frames: β, γ worst 3.75°, φ, ψ
    up to the mirror worst 9.0°, per-seed RMSE ≤ 1.4°. Bounds: α worst < 1°; β, γ RMSE
    < 1°, worst < 5°; φ, ψ up to the mirror RMSE < 2°, worst < 10°; error_px < 0.5 px.
    """
    truth, fitted, px, statuses = _single_view_fit(SIDE)
    err = np.abs(fitted - truth)
    mirrored = np.abs(fitted * [-1.0, -1.0, 1.0, 1.0, 1.0] + [360.0, 0.0, 0.0, 0.0, 0.0] - truth)
    nearer = np.where((err[:, :2].sum(axis=1) <= mirrored[:, :2].sum(axis=1))[:, None], err, mirrored)
    assert all(s is Status.OK for s in statuses)
    assert px.max() < 0.5
    assert err[:, 2].max() < 1.0
    assert np.all(_rmse(err[:, 3:]) < 1.0) and err[:, 3:].max() < 5.0
    assert np.all(_rmse(nearer[:, :2]) < 2.0) and nearer[:, :2].max() < 10.0


def test_top_view_alone_recovers_phi_and_a_posture_that_explains_the_view():
    """Top view only: it loses the vertical (y). φ, the leg's azimuth, is seen; the rest is
    ambiguous in depth, and without labels the fit may also assign the blobs to other
    markers, or put two markers on one blob (the paper's Fig. 9): measured in 30 % of
    frames the fitted posture projects > 1 px from the truth's projection, though its
    error_px stays small.

    Measured (3 seeds, 120 frames): RMSE φ 2.8°, ψ 11.0°, α 4.7°, β 8.7°, γ 24.2° (worst
    12.6°, 38°, 16°, 42°, 77°); error_px median 0.02 px, worst 6.3 px; all ok. Over 10
    seeds pooled: 1.7°, 8.1°, 2.7°, 7.1°, 20.6° (the paper's Table 2, top view: 14.7°,
    10.4°, 23.7°, 29.6°, 52.4°). Bounds on the pooled RMSE: φ < 6°, ψ < 20°, α < 10°,
    β < 20°, γ < 40° (random postures: γ ~57°); error_px median < 0.1 px, all ok.
    """
    truth, fitted, px, statuses = _single_view_fit(TOP)
    rmse = _rmse(np.abs(fitted - truth))
    assert all(s is Status.OK for s in statuses)
    assert np.median(px) < 0.1
    assert np.all(rmse < [6.0, 20.0, 10.0, 20.0, 40.0]), rmse.round(2)


# ---- 6. interlaced footage -------------------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1])
def test_interlaced_footage_through_the_cli(tmp_path, seed):
    """``mocap synth --interlaced`` (40 fields = 20 frames, FFV1 file), then ``mocap fit
    --deinterlace``: each field detected on its own rows, its markers located by a disc
    model (``core.fields``; the plain weighted centroid was off by up to ±0.28 px).

    Measured over 8 seeds: all ok; RMSE ≤ 0.040° per DOF, worst field 0.25°; error_px
    median 0.05–0.06 px, worst 3.6 px (seeds 0, 1: RMSE ≤ 0.033°, 0.028°, worst 0.071°,
    0.076°; with the centroid alone: 0.94°, 0.65°, worst 1.7°). Bounds: RMSE < 0.15° per
    DOF, every field < 0.5°, median error_px < 0.2 px, all ok, fields alternating even/odd.
    """
    model, rig = EXAMPLES / LOCUST / "model.xml", EXAMPLES / LOCUST / "rig.json"
    synth = _cli("synth", "--model", model, "--rig", rig, "--out", tmp_path / "clip", "--samples", 40,
                 "--seed", seed, "--interlaced")
    assert synth.exit_code == 0, synth.output
    fit = _cli("fit", tmp_path / "clip" / "video0.avi", "--model", model, "--rig", rig,
               "--out", tmp_path / "out", "--marker-diameter-px", MARKER_PX, "--deinterlace",
               "--seed", seed)
    assert fit.exit_code == 0, fit.output
    table = read_angles_csv(tmp_path / "out" / "angles.csv")
    _, truth = read_truth_csv(tmp_path / "clip" / "truth.csv")
    err = np.abs(table.dofs - truth)
    assert len(table.samples) == 40 and table.fields[:2] == ["even", "odd"]
    assert all(s is Status.OK for s in table.statuses)
    assert np.all(_rmse(err) < 0.15), _rmse(err).round(3)
    assert err.max() < 0.5
    assert np.median(table.errors) < 0.2


# ---- 7. frames that went wrong are flagged ---------------------------------------------------


BAD = np.arange(12, 16)  # four consecutive frames of 30


def _garbage_detections(case: str, truth: np.ndarray, rng: np.random.Generator) -> list[Detections]:
    """Detections of ``truth`` (30 frames) whose frames BAD are garbage of the kind ``case``."""
    _, rig = _example(LOCUST)
    drop = np.zeros((len(truth), 2, 4), dtype=bool)
    if case.startswith("most_missing"):  # three of the four markers gone from one view
        drop[BAD, SIDE if case.endswith("side") else TOP, 1:] = True
    elif case == "view_lost":
        drop[BAD, TOP, :] = True
    detections = _detections(LOCUST, truth, rng, drop=drop)
    if case.startswith("random"):  # one view's blobs replaced by four random points in its roi
        view = SIDE if case.endswith("side") else TOP
        x, y, w, h = rig.views[view].roi
        for t in BAD:
            views = [detections[t].view(v) for v in (SIDE, TOP)]
            views[view] = np.column_stack([rng.uniform(x, x + w, 4), rng.uniform(y, y + h, 4)])
            detections[t] = Detections.from_views(views)
    elif case.startswith("rig"):  # the frames of another camera set-up
        wrong = {"rig_shifted": _moved_rig(rig, shift_px=(20.0, 10.0)),
                 "rig_zoomed": _moved_rig(rig, zoom=0.85), "rig_swapped": _swapped_rig(rig)}[case]
        detections[BAD[0] : BAD[-1] + 1] = _detections(LOCUST, truth[BAD], rng, rig=wrong)
    return detections


@pytest.mark.parametrize(
    "case",
    ["random_side", "random_top", "most_missing_side", "most_missing_top", "view_lost",
     "rig_shifted", "rig_zoomed", "rig_swapped"],
)
def test_garbage_frames_are_flagged_and_the_frames_around_them_are_not(case):
    """Frames 12–15 of 30 carry garbage detections (seeds 0, 1): one view's blobs replaced
    by random points; three of a view's four markers missing; the top view lost; or the
    frames of another rig (shifted 20, 10 px; zoomed ×0.85; side and top cameras swapped).

    Measured: every garbage frame over_threshold after 5 attempts, its DOFs finite and in
    range, error_px ≥ 122 (random), ≥ 149 (most missing), 20.0 (view lost: 4 markers ×
    the 5 px empty-view charge; the posture itself is right, from the other view), ≥ 77
    (shifted), ≥ 34.9 (zoomed), ≥ 154 px (swapped); the frames around them ok, within
    0.10°. Bounds: garbage frames over_threshold, error_px > 15 px, attempts = 5 or
    settled (``core.fit.reanalyse_image``), DOFs finite and in range; the other frames ok
    and within 0.3°.
    """
    model, _ = _example(LOCUST)
    good = np.setdiff1d(np.arange(30), BAD)
    for seed in (0, 1):
        truth, rng = _movement(LOCUST, 30, seed)
        result = _fit(LOCUST, _garbage_detections(case, truth, rng), seed)
        err = _abs_errors(result, truth).max(axis=1)
        for t in BAD:
            fit = result.fits[t]
            assert fit.status is Status.OVER_THRESHOLD and fit.error > 15.0, (seed, t, fit.error)
            assert fit.attempts == PARAMS.max_attempts or fit.settled
            assert np.all((fit.dofs >= model.lower) & (fit.dofs <= model.upper))
        assert all(result.fits[t].status is Status.OK for t in good), seed
        assert err[good].max() < 0.3, seed


def test_frames_without_detections_get_empty_cells_through_the_cli(tmp_path):
    """Frames 8 and 9 of 24 rendered without markers (noise only), written to an FFV1 file
    and fitted by ``mocap fit``: their rows say no_detections with empty DOF and error_px
    cells and 0 attempts; report.json counts them; the others are ok and accurate
    (measured worst 0.09°, 0.07°, 0.10° for seeds 5–7; bound 0.3°).
    """
    model, rig = _example(LOCUST)
    truth, rng = _movement(LOCUST, 24, 5)
    drop = np.zeros((24, 2, 4), dtype=bool)
    drop[[8, 9]] = True
    video = tmp_path / "blank.avi"
    frames = render_frames(model, rig, truth, rng=rng, marker_diameter_px=MARKER_PX, drop=drop)
    assert write_video(video, frames, fps=50.0) == 24
    fit = _cli("fit", video, "--model", EXAMPLES / LOCUST / "model.xml", "--rig",
               EXAMPLES / LOCUST / "rig.json", "--out", tmp_path / "out", "--marker-diameter-px", MARKER_PX)
    assert fit.exit_code == 0, fit.output
    with (tmp_path / "out" / "angles.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    for row in rows[8:10]:
        assert row["status"] == "no_detections" and row["attempts"] == "0"
        assert [row[name] for name in [*model.dof_names, "error_px"]] == [""] * 6
    others = [r for i, r in enumerate(rows) if i not in (8, 9)]
    assert all(r["status"] == "ok" for r in others)
    fitted = np.array([[float(r[name]) for name in model.dof_names] for r in others])
    assert np.abs(fitted - np.delete(truth, [8, 9], axis=0)).max() < 0.3
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["status"] == {"ok": 22, "over_threshold": 0, "no_detections": 2}


def test_a_frame_fitted_in_a_local_minimum_is_flagged():
    """Clean two-view footage (60 frames, 4 sequences): no frame may be > 2° off and ok.

    Found over 60 seeds (3600 frames): SA ended at 5.5-7.2 px where the truth scores
    ~0.1 px in exactly these 3 frames (seeds 9, 16, 26), 11.7-15.2° off, ok under the
    10 px threshold. Now the blob reading removes those minima, and an image far above
    the sequence's typical objective is re-analysed (``FitParams.outlier_factor``):
    measured worst 0.11° on these seeds, every frame at its first attempt.
    """
    wrong = []
    for seed in (9, 16, 26):
        truth, rng = _movement(LOCUST, 60, seed, n_sequences=4)
        result = _fit(LOCUST, _detections(LOCUST, truth, rng), seed)
        wrong += [(seed, *w) for w in _wrong_but_ok(result, _abs_errors(result, truth))]
    assert wrong == []
