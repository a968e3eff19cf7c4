"""The whole-animal benchmark subjects (bench/subjects) load and move sanely.

Every subject's files parse (FORMATS §1, §2), its natural movement stays in the DOF
ranges, and every marker of every posture, the unmodelled one included, projects
inside every camera's image with a margin: otherwise the benchmark would measure
markers the cameras cannot see.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from core.model import KinematicModel
from core.rig import Rig

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from bench.basins import REASONS, why_off
from bench.chain import tail
from bench.random_trees import filmed, random_model
from bench.subjects import CAMERAS, HEXAPOD_CAMERAS, NAMES, camera_choice, load

SUBJECTS = Path(__file__).resolve().parents[2] / "bench" / "subjects"
MARGIN_PX = 5.0


@pytest.mark.parametrize("name", ["hexapod", "freefly", "biped", "fullbody", "rat", "spider"])
def test_subject_files_load(name):
    model = KinematicModel.from_xml(SUBJECTS / name / "model.xml")
    rig = Rig.from_json(SUBJECTS / name / "rig.json")
    assert all(v.projection["type"] == "pinhole" for v in rig.views)
    if name == "hexapod":  # fixed thorax with 3 markers; 6 legs × 7 DOFs, 4 markers each
        assert len(rig.views) == 6 and len(model.dofs) == 42 and len(model.markers) == 27
        assert not any(d.joint == "thorax" for d in model.dofs)
        assert sum(m.joint == "thorax" for m in model.markers) == 3
    elif name == "freefly":  # the same fly, its thorax with 3 translations and 3 rotations
        hexapod = KinematicModel.from_xml(SUBJECTS / "hexapod" / "model.xml")
        assert len(rig.views) == 6 and len(model.dofs) == 48
        assert model.dof_names[6:] == hexapod.dof_names and model.markers == hexapod.markers
        assert sorted(d.axis for d in model.dofs if d.joint == "thorax") == ["tx", "ty", "tz", "x", "y", "z"]
    elif name == "spider":  # free cephalothorax (4 markers), a 2-DOF abdomen, 8 legs × 6 DOFs
        assert len(rig.views) == 4
        assert len(model.dofs) == 6 + 2 + 8 * 6 and len(model.markers) == 4 + 2 + 8 * 4
        assert sorted(d.axis for d in model.dofs if d.joint == "ceph") == ["tx", "ty", "tz", "x", "y", "z"]
        assert any(any(v != 0.0 for v in view.projection["dist"]) for view in rig.views)
    else:  # pelvis with 3 translations and 3 rotations; hip 3 DOFs, knee, ankle
        assert len(rig.views) == (6 if name == "fullbody" else 3)
        assert sum(d.joint == "R_knee" for d in model.dofs) == 1
        assert sum(d.joint == "R_ankle" for d in model.dofs) == 1
        pelvis = [d.axis for d in model.dofs if d.joint == "pelvis"]
        assert sorted(pelvis) == ["tx", "ty", "tz", "x", "y", "z"]
        assert sum(d.joint == "R_hip" for d in model.dofs) == 3
        assert sum(m.joint == "pelvis" for m in model.markers) == 3
    if name == "fullbody":  # the biped's legs, spine 3, neck 3, arms 6 DOFs with 6 markers below
        biped = KinematicModel.from_xml(SUBJECTS / "biped" / "model.xml")
        assert model.dof_names[: len(biped.dofs)] == biped.dof_names
        assert len(model.dofs) == 34 and len(model.markers) == 38
        arm = {f"{side}_{j}": side for side in "RL" for j in ("shoulder", "elbow", "forearm", "wrist")}
        for side in "RL":
            assert sum(arm.get(d.joint) == side for d in model.dofs) == 6
            assert sum(arm.get(m.joint) == side for m in model.markers) == 6


def test_fullbody_tree_splits_twice():
    """The pelvis carries two legs and the spine, the thorax carries the neck and two arms:
    the nested splits a recursive decomposition is measured on."""
    model = KinematicModel.from_xml(SUBJECTS / "fullbody" / "model.xml")

    def children(joint: str) -> list[str]:
        return sorted(j.name for j in model.joints if j.parent == joint)

    assert children("pelvis") == ["L_hip", "R_hip", "lumbar"]
    assert children("lumbar") == ["L_shoulder", "R_shoulder", "neck"]
    assert sum(m.joint == "lumbar" for m in model.markers) == 7  # C7, T10, CLAV, STRN, RBAK, SHO


@pytest.mark.parametrize(("name", "cameras"),
                         [(n, c) for n in CAMERAS for c in CAMERAS[n]]
                         + [(n, None) for n in NAMES if n not in CAMERAS])
def test_movement_projects_inside_every_image(name, cameras):
    subject = load(name, cameras)
    truth = _moves_inside(subject)
    if name in ("hexapod", "freefly"):  # walking is smooth (the others jump on purpose: kicks, new passes)
        assert np.abs(np.diff(truth, axis=0)).max() < 30.0


@pytest.mark.parametrize("limbs", [False, True], ids=["tail", "spine with limbs"])
@pytest.mark.parametrize("segments", [2, 4, 8, 12, 16, 24])
def test_a_tail_swings_inside_every_image(segments, limbs):
    """``bench/chain.py``'s tails and spines: the same 80 mm bent by the same 90° whatever
    the count, the limbs swinging below."""
    _moves_inside(tail(segments, limbs))


@pytest.mark.parametrize("markers", [1, 2])
@pytest.mark.parametrize("seed", range(4))
def test_a_random_tree_moves_inside_every_image(seed, markers):
    """``bench/random_trees.py``'s models: a root with three markers and one to six branches
    of two to four joints, ``markers`` markers per segment; with two, at most two DOFs per
    joint after a branch's first. Filmed by two and by three cameras on the ring (three with
    wide-angle lenses too), and by a side and a top camera, inside every image."""
    model = random_model(np.random.default_rng([seed, 0]), markers)
    joints = {m.joint for m in model.markers} - {"root"}
    assert 1 <= sum(j.endswith("j0") for j in joints) <= 6
    assert sum(m.joint == "root" for m in model.markers) == 3
    assert len(model.markers) == 3 + markers * len(joints)
    if markers == 2:
        later = [d for d in model.dofs if not d.joint.endswith("j0")]
        assert all(sum(d.joint == j for d in later) <= 2 for j in joints)
    for cameras in (2, 3):
        _moves_inside(filmed(model, cameras, 100.0))
    _moves_inside(filmed(model, 2, 100.0, "side-top"))
    _moves_inside(filmed(model, 3, 100.0, "ring", -0.3))


def _moves_inside(subject) -> np.ndarray:
    """150 images of ``subject``'s movement (returned): within the DOF ranges, every marker
    (the unmodelled ones too) MARGIN_PX inside every view's image."""
    truth = subject.trajectory(150, np.random.default_rng(5))
    model = subject.with_unmodelled_markers()
    assert len(model.markers) == len(subject.model.markers) + len(subject.unmodelled)
    assert truth.shape == (150, len(subject.model.dofs))
    assert np.all(truth >= subject.model.lower) and np.all(truth <= subject.model.upper)
    proj = subject.rig.project(model.marker_positions(truth))  # (T, V, M + 1, 2)
    for v, view in enumerate(subject.rig.views):
        x, y, w, h = view.roi if view.roi is not None else (0, 0, *subject.size_of(view.video))
        u, vv = proj[:, v, :, 0], proj[:, v, :, 1]
        assert np.all(np.isfinite(proj[:, v]))
        assert u.min() >= x + MARGIN_PX and u.max() <= x + w - MARGIN_PX, view.name
        assert vv.min() >= y + MARGIN_PX and vv.max() <= y + h - MARGIN_PX, view.name
    return truth


def test_free_fly_walks_as_the_tethered_one_on_a_moving_thorax():
    """Same seed, same legs; the thorax turns by more than 10 degrees and shifts by more
    than a tenth of a millimetre."""
    rng = 3
    tethered = load("hexapod").trajectory(200, np.random.default_rng(rng))
    free = load("freefly").trajectory(200, np.random.default_rng(rng))
    np.testing.assert_array_equal(free[:, 6:], tethered)
    thorax = free[:, :6]
    assert np.ptp(thorax[:, 3]) > 10.0 and np.ptp(thorax[:, :3], axis=0).max() > 0.1


def test_hexapod_camera_subsets_are_views_of_the_six():
    six = load("hexapod", 6).rig
    for cameras, views in HEXAPOD_CAMERAS.items():
        rig = load("hexapod", cameras).rig
        assert rig.n_videos == cameras
        assert [v.projection for v in rig.views] == [six.views[i].projection for i in views]


def test_rat_is_small_in_its_images():
    """Consecutive markers from the rat's knee to its toe lie 10-40 px apart (median; 1.4 px per
    mm at 600 mm), its two lateral views see both iliac crests nearly on top of each other,
    and the two-camera variant keeps the lateral pair."""
    subject = load("rat")
    model = subject.model
    assert len(model.dofs) == 16 and len(model.markers) == 13 and len(subject.unmodelled) == 2
    assert [m.name for m in model.markers if m.joint == "pelvis"] == ["R_crest", "L_crest", "tail_base"]
    truth = subject.trajectory(200, np.random.default_rng(1))
    proj = subject.rig.project(model.marker_positions(truth))  # (T, V, M, 2)
    names = [m.name for m in model.markers]
    chain = [names.index(f"R_{m}") for m in ("knee", "ankle", "mt5", "toe")]
    steps = np.linalg.norm(np.diff(proj[:, 0, chain], axis=1), axis=-1)  # right view, px
    assert 10.0 < np.median(steps) < 40.0
    crests = np.linalg.norm(proj[:, :2, 0] - proj[:, :2, 1], axis=-1)  # both lateral views
    assert np.median(crests) < 10.0  # closer than two 5 px markers
    two = load("rat", 2).rig
    assert [v.name for v in two.views] == ["right", "left"] and two.n_videos == 2


def test_mouse_is_one_camera_and_a_mirror():
    """The mouse: a trunk root with 6 DOFs and four 5-DOF limbs, seen by one camera from the
    side and through a mirror from below (two affine views in one frame, split by their
    rois); its left and right limbs overlap in the side view and lie apart in the bottom one."""
    subject = load("mouse")
    model, rig = subject.model, subject.rig
    assert len(model.dofs) == 26 and len(model.markers) == 24 and len(subject.unmodelled) == 2
    assert [d.axis for d in model.dofs if d.joint == "pelvis"] == ["tx", "ty", "tz", "y", "x", "z"]
    assert sorted(j.name for j in model.joints if j.parent == "pelvis") == [
        "L_hip", "L_shoulder", "R_hip", "R_shoulder"]
    assert [v.projection["type"] for v in rig.views] == ["affine", "affine"]
    assert rig.n_videos == 1 and [v.roi[1] for v in rig.views] == [0, 256]
    truth = subject.trajectory(200, np.random.default_rng(2))
    proj = rig.project(model.marker_positions(truth))  # (T, V, M, 2)
    names = [m.name for m in model.markers]
    gap = np.linalg.norm(proj[:, :, names.index("R_knee")] - proj[:, :, names.index("L_knee")], axis=-1)
    side, bottom = np.percentile(gap, 10, axis=0)
    assert side < 10.0 < 20.0 < bottom  # px: the knees cross in the side view, never below


def test_camera_choice_defaults():
    assert camera_choice("hexapod", None) == 6 and camera_choice("hexapod", 2) == 2
    assert camera_choice("rat", None) is None and camera_choice("rat", 2) == 2
    assert camera_choice("rat", 6) is None and camera_choice("biped", 2) is None


def test_load_refuses_unknown_subjects_and_cameras():
    with pytest.raises(ValueError, match="subject"):
        load("scorpion")
    with pytest.raises(ValueError, match="camera"):
        load("biped", 3)


def test_occlusion_hides_the_asked_share_in_runs():
    """bench/animals.py's occlusion: the stationary hidden share and mean run length asked,
    reproducible from the generator; impossible pairs refused."""
    from bench.animals import _run_starts, occlusion_mask

    hidden = occlusion_mask((4000, 3, 10), 0.2, 5.0, np.random.default_rng(3))
    assert hidden.dtype == bool and hidden.shape == (4000, 3, 10)
    assert abs(hidden.mean() - 0.2) < 0.01
    assert abs(hidden.sum() / _run_starts(hidden) - 5.0) < 0.2
    again = occlusion_mask((4000, 3, 10), 0.2, 5.0, np.random.default_rng(3))
    assert np.array_equal(hidden, again)
    assert not occlusion_mask((50, 2, 4), 0.0, 2.0, np.random.default_rng(0)).any()
    with pytest.raises(ValueError, match="no hidden fraction"):
        occlusion_mask((10, 1, 1), 0.8, 2.0, np.random.default_rng(0))


def test_occlusion_everywhere_hides_a_marker_from_every_view_at_once():
    """``--everywhere``: each marker hidden from all views in the same images, and its blobs
    gone from every view there (the ghosts drawn still)."""
    from bench.animals import render_and_detect

    subject = load("locust")
    data = render_and_detect(subject, 40, soft=False, ghosts=0, rng=np.random.default_rng(1),
                             occlusion=0.2, everywhere=True)
    hidden = data.hidden
    assert hidden.any() and np.array_equal(hidden, np.repeat(hidden[:, :1], hidden.shape[1], axis=1))
    markers = len(subject.model.markers)
    for det, h in zip(data.detections, hidden, strict=True):
        assert det.counts.tolist() == (markers - h.sum(axis=1)).tolist()


def test_a_lost_claw_is_missing_from_every_view_of_every_image():
    """``--lost-claw``: the first branch's last marker (the hexapod's front claw) has no blob
    in any image: one blob fewer than the same images with it, in every view but those where
    it fused with another marker; and with ``--occlusion`` both hide."""
    from bench.animals import lost_marker, render_and_detect

    subject = load("hexapod", 3)
    claw = lost_marker(subject.model)
    assert subject.model.markers[claw].name == "LF_claw"
    data = render_and_detect(subject, 6, soft=False, ghosts=0, rng=np.random.default_rng(2), lost_claw=True)
    assert data.hidden[:, :, claw].all() and data.hidden.sum() == data.hidden[:, :, claw].sum()
    plain = render_and_detect(subject, 6, soft=False, ghosts=0, rng=np.random.default_rng(2))
    fewer = np.array([p.counts - d.counts for p, d in zip(plain.detections, data.detections, strict=True)])
    assert set(fewer.ravel().tolist()) <= {0, 1} and fewer.mean() > 0.8
    both = render_and_detect(subject, 40, soft=False, ghosts=0, rng=np.random.default_rng(2),
                             occlusion=0.2, lost_claw=True).hidden
    assert both[:, :, claw].all() and both.sum() > both[:, :, claw].sum()
    assert lost_marker(load("locust").model) == len(load("locust").model.markers) - 1


def test_glints_lie_on_the_body_and_add_blobs():
    """``--glints``: every glint lies within a marker diameter of a segment of the posture in
    its own view (a joint to a child joint or to a marker), each view and image draws its
    own, and they add blobs (those that fall on a marker fuse with it)."""
    from bench.animals import glint_pixels, render_and_detect

    subject = load("rat")
    truth = subject.trajectory(6, np.random.default_rng(4))
    glints = glint_pixels(subject, truth, 4, 5.0, np.random.default_rng(5))
    assert glints.shape == (6, len(subject.rig.views), 4, 2)
    model = subject.model
    index = {j.name: i for i, j in enumerate(model.joints)}
    for t, q in enumerate(truth):
        joints = subject.rig.project(model.joint_transforms(q)[None, :, :3, 3])[0]  # (V, J, 2)
        markers = subject.rig.project(model.marker_positions(q)[None])[0]
        segments = [(joints[:, index[j.parent]], joints[:, i]) for i, j in enumerate(model.joints)
                    if j.parent is not None]
        segments += [(joints[:, index[m.joint]], markers[:, k]) for k, m in enumerate(model.markers)]
        for v in range(len(subject.rig.views)):
            for g in glints[t, v]:
                gaps = [_distance_to_segment(g, a[v], b[v]) for a, b in segments]
                assert min(gaps) <= 5.0 + 1e-6
    assert not np.allclose(glints[0, 0], glints[0, 1]) and not np.allclose(glints[0, 0], glints[1, 0])
    plain = render_and_detect(subject, 6, soft=False, ghosts=0, rng=np.random.default_rng(6))
    glinting = render_and_detect(subject, 6, soft=False, ghosts=0, rng=np.random.default_rng(6), glints=4)
    extra = np.array([g.counts - p.counts
                      for g, p in zip(glinting.detections, plain.detections, strict=True)])
    assert extra.min() >= 0 and extra.max() <= 4 and extra.mean() > 1  # some fuse with a marker


def _distance_to_segment(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    ab = b - a
    u = np.clip(np.dot(p - a, ab) / max(float(np.dot(ab, ab)), 1e-12), 0.0, 1.0)
    return float(np.linalg.norm(p - (a + u * ab)))


@pytest.mark.parametrize("subject", ["locust", "hexapod", "spider"])
def test_a_calibrated_rig_moves_every_projection_by_the_asked_shift(subject):
    """bench/imperfect.py's rig error: every view's image (affine, pinhole with distortion)
    lands exactly ``shift_px`` away, each view in its own direction."""
    from bench.imperfect import calibrated_rig

    rig = load(subject).rig
    points = np.random.default_rng(0).normal(0.0, 2.0, (20, 3))
    shifted = calibrated_rig(rig, 1.5, np.random.default_rng(4))
    moved = shifted.project(points) - rig.project(points)  # (V, N, 2)
    assert np.allclose(np.linalg.norm(moved, axis=-1), 1.5)
    assert np.allclose(moved, moved[:, :1])  # one shift per view
    assert len({tuple(np.round(m[0], 6)) for m in moved}) == len(rig.views)


def test_a_measured_model_scales_each_length_by_its_own_factor():
    """bench/imperfect.py's model error: joint offsets (not the root's position) and marker
    positions scaled, each vector by one factor; DOFs unchanged; no error, no change."""
    from bench.imperfect import measured_model

    model = load("rat").model
    assert measured_model(model, 0.0, np.random.default_rng(0)) == model
    measured = measured_model(model, 0.05, np.random.default_rng(0))
    assert measured.dofs == model.dofs and measured.joints[0] == model.joints[0]
    pairs = [(a.offset, b.offset) for a, b in zip(model.joints[1:], measured.joints[1:], strict=True)]
    pairs += [(a.position, b.position) for a, b in zip(model.markers, measured.markers, strict=True)]
    factors = []
    for true, off in pairs:
        true, off = np.array(true), np.array(off)
        if np.linalg.norm(true) > 0:
            factor = np.linalg.norm(off) / np.linalg.norm(true)
            assert np.allclose(off, factor * true)
            factors.append(factor)
    assert 0.02 < np.std(factors) < 0.08 and not np.allclose(factors, 1.0)


def test_an_off_image_is_put_down_to_the_image_before_the_choice_or_the_search():
    """``bench/basins.py``'s reasons, in their order: an image whose own minimum is off
    cannot be helped; a candidate within 5° left means the choice; a truth that scores
    lower by more than the floor means the search; one within it, a tie."""
    image, choice, search, tie = REASONS
    assert why_off(8.0, 1.0, 10.0, 2.0, 0.5) == image
    assert why_off(1.0, 4.0, 10.0, 2.0, 0.5) == choice
    assert why_off(1.0, 30.0, 10.0, 9.4, 0.5) == search
    assert why_off(1.0, 30.0, 10.0, 9.6, 0.5) == tie
    assert why_off(1.0, 30.0, 10.0, 12.0, 0.5) == tie


@pytest.mark.parametrize("name", ["rat", "stick"])
def test_a_subject_cut_at_its_frames_edge_moves_as_before_with_that_share_beyond(name):
    """``--beyond``: each view's roi ends where about the share of its projections lies
    beyond (more where many share that column: the stick insect's fixed coxa marker), inside
    its own roi where it has one (the stick insect's two views share a frame); the rig fitted
    with knows it, and the movement is the subject's own."""
    from bench.animals import cut_at_edge

    subject = load(name)
    truth = subject.trajectory(30, np.random.default_rng(0))
    cut = cut_at_edge(subject, truth, 0.2)
    assert np.array_equal(cut.trajectory(30, np.random.default_rng(0)), truth)
    projected = subject.rig.project(subject.model.marker_positions(truth))
    for v, (view, was) in enumerate(zip(cut.rig.views, subject.rig.views, strict=True)):
        beyond = np.mean(projected[:, v, :, 0] >= view.roi[0] + view.roi[2])
        assert 0.15 < beyond < (0.25 if name == "rat" else 0.35)
        if was.roi is not None:
            assert view.roi[:2] == was.roi[:2] and view.roi[2] < was.roi[2] and view.roi[3] == was.roi[3]
        assert np.isfinite(cut.rig.regions[v]).all()


def test_a_leg_out_of_one_of_two_frames_pulled_back_in_is_searched_again_reading_the_edges():
    """The spider filmed by two cameras, each seeing the left of its frame (``--beyond
    0.1``), image 0: the first attempt's SA reads plain Eq. 5, which charges the markers of
    a hind leg beyond the edge their distance to blobs inside, and pulls the leg in, tens of
    degrees off. Its re-analysis reads the edges (``FitParams.search_edges``) and finds the
    truth's minimum, 40 px lower; reading plain Eq. 5 again, every attempt pulled it back in
    (docs/BENCH_SUBJECTS.md, stop 53)."""
    from bench.animals import angle_errors, cut_at_edge, fit_params, render_and_detect
    from core.fit import first_attempt, flip_geometry, reanalyse_image
    from core.histogram import Histograms

    subject = load("spider", 2)
    subject = cut_at_edge(subject, subject.trajectory(60, np.random.default_rng(0)), 0.1)
    data = render_and_detect(subject, 1, soft=False, ghosts=2, rng=np.random.default_rng(0))
    model, det, params = subject.model, data.detections[0], fit_params(data)[0]
    prior = Histograms.uniform(model, prior_weight=100.0)
    fit = first_attempt(det, 0, model=model, rig=subject.rig, histograms=prior, params=params, seed=0,
                        geometry=flip_geometry(model, subject.rig))

    def off(dofs: np.ndarray) -> float:
        return float(np.abs(angle_errors(model, dofs[None], data.truth[:1])[0][model.rotational]).max())

    assert off(fit.dofs) > 30.0 and fit.outside[0] > 0
    for _ in range(2):
        fit = reanalyse_image(det, fit, model=model, rig=subject.rig, histograms=prior, params=params, seed=0)
    assert off(fit.dofs) < 1.0


def _stick_beyond():
    """The stick insect leg with 10 % of its projections beyond its views' rois (``bench/animals.py
    --subject stick --images 60 --beyond 0.1``, seed 0): subject, rendered images and the fit's
    settings."""
    from bench.animals import cut_at_edge, fit_params, render_and_detect

    subject = load("stick")
    subject = cut_at_edge(subject, subject.trajectory(60, np.random.default_rng(0)), 0.1)
    data = render_and_detect(subject, 60, soft=False, ghosts=2, rng=np.random.default_rng(0))
    return subject, data, fit_params(data)[0]


def test_an_image_left_in_a_wrong_minimum_by_its_warm_starts_is_searched_from_the_next_image():
    """Images 32-35 of the stick insect leg (``--beyond 0.1``, seed 0): SA at image 32 ends
    in a minimum 26° off, and the warm starts carry it on; image 35 kept it at 0.66 px, ``ok``,
    with no alternative, while its truth scores 0.34 px. Image 36 is right, and its posture,
    refined on image 35, finds the truth's minimum: the chunk's backward sweep
    (``core.fit.seen_from_after``) keeps it, the wrong one as its alternative."""
    from bench.animals import angle_errors
    from core.histogram import Histograms
    from core.sequence import fit_chunk

    subject, data, params = _stick_beyond()
    model = subject.model
    fits = fit_chunk(data.detections[:37], model=model, rig=subject.rig, params=params, seed=0,
                     histograms=Histograms.uniform(model, prior_weight=100.0)).fits
    off = np.abs(angle_errors(model, np.array([f.dofs for f in fits]), data.truth[:37])[:, model.rotational])
    assert off[35].max() < 1.0 and off[36].max() < 1.0
    alpha = [abs(a.dofs[2] - fits[35].dofs[2]) for a in fits[35].alternatives]
    assert fits[35].objective < 0.4 and max(alpha) > 20


def test_the_next_images_posture_is_kept_only_where_it_lands_lower():
    """``seen_from_after`` on image 35 of the same run: the wrong minimum (alpha and psi
    26.8° and 18.3° off; 0.54-0.66 px by the machine, the truth's 0.34 px) offered the right
    posture becomes it, and keeps the wrong one as its alternative (within the tolerance);
    the right fit offered the wrong posture keeps its posture and reports the wrong one (no
    lower, within the tolerance) as its alternative, not for the choice by continuity; offered
    a posture a few degrees from its own (nothing to search), it stays as it is."""
    from core.error import view_offsets
    from core.fit import ImageFit, Status, seen_from_after
    from core.treefit import refine_whole

    subject, data, params = _stick_beyond()
    model, rig, det = subject.model, subject.rig, data.detections[35]

    def fitted(start: np.ndarray) -> ImageFit:
        q, error, objective = refine_whole(start.copy(), det, model, rig, params, view_offsets(None, rig))
        return ImageFit(35, q, error, objective, 1, Status.OK, 100, tuple(det.counts.tolist()))

    right = fitted(data.truth[35])
    wrong = fitted(data.truth[35] + np.array([0.0, 0.0, 26.8, 18.3, 0.0, 0.0]))
    assert wrong.objective > right.objective + 0.1 and abs(wrong.dofs[2] - right.dofs[2]) > 20

    def offered(fit: ImageFit, after: np.ndarray) -> ImageFit:
        return seen_from_after(fit, after[None], det, model=model, rig=rig, params=params)

    reported = offered(right, wrong.dofs)
    assert np.array_equal(reported.dofs, right.dofs) and reported.objective == right.objective
    [alternative] = reported.alternatives
    assert alternative.objective == pytest.approx(wrong.objective) and not alternative.minimum
    assert offered(right, right.dofs + 2.0) is right
    lowered = offered(wrong, right.dofs)
    assert lowered.objective == pytest.approx(right.objective, abs=1e-6)
    assert lowered.status is Status.OK and not lowered.settled
    assert [a.objective for a in lowered.alternatives] == pytest.approx([wrong.objective])


def test_the_labelled_reference_is_the_posture_whose_markers_lie_nearest_in_3d():
    """``bench.reference.labelled_ik``: given a posture's own markers it returns that posture
    from a start 8° away in every angle; given those markers each moved by 2 mm (the rat is in
    mm), its posture's markers lie nearer them, in summed squared distance, than the true
    posture's and than any small step from it (a least-squares minimum, not just a descent)."""
    from bench.reference import labelled_ik

    subject = load("rat")
    model = subject.model
    truth = subject.trajectory(3, np.random.default_rng(0))[1]
    markers = model.marker_positions(truth)
    start = np.where(model.rotational, truth + 8.0, truth + 2.0)
    assert np.abs(labelled_ik(model, markers, start) - truth).max() < 1e-4

    slid = markers + np.random.default_rng(1).normal(0.0, 2.0, markers.shape)

    def cost(q: np.ndarray) -> float:
        return float(np.sum((model.marker_positions(q) - slid) ** 2))

    fitted = labelled_ik(model, slid, truth)
    assert cost(fitted) < cost(truth)
    steps = 0.05 * np.eye(len(truth))
    inside = [q for q in (*(fitted + steps), *(fitted - steps))
              if np.all(q >= model.lower) and np.all(q <= model.upper)]
    assert inside and all(cost(q) >= cost(fitted) - 1e-9 for q in inside)
