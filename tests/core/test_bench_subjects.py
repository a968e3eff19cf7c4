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

from bench.subjects import HEXAPOD_CAMERAS, NAMES, load

SUBJECTS = Path(__file__).resolve().parents[2] / "bench" / "subjects"
MARGIN_PX = 5.0


@pytest.mark.parametrize("name", ["hexapod", "biped", "fullbody"])
def test_subject_files_load(name):
    model = KinematicModel.from_xml(SUBJECTS / name / "model.xml")
    rig = Rig.from_json(SUBJECTS / name / "rig.json")
    assert all(v.projection["type"] == "pinhole" for v in rig.views)
    if name == "hexapod":  # fixed thorax with 3 markers; 6 legs × 7 DOFs, 4 markers each
        assert len(rig.views) == 6 and len(model.dofs) == 42 and len(model.markers) == 27
        assert not any(d.joint == "thorax" for d in model.dofs)
        assert sum(m.joint == "thorax" for m in model.markers) == 3
    else:  # pelvis with 3 translations and 3 rotations; hip 3 DOFs, knee, ankle
        assert len(rig.views) == (6 if name == "fullbody" else 3)
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
                         [("hexapod", c) for c in HEXAPOD_CAMERAS] + [(n, None) for n in NAMES[1:]])
def test_movement_projects_inside_every_image(name, cameras):
    subject = load(name, cameras)
    truth = subject.trajectory(150, np.random.default_rng(5))
    model = subject.with_unmodelled_marker()
    assert truth.shape == (150, len(subject.model.dofs))
    assert np.all(truth >= subject.model.lower) and np.all(truth <= subject.model.upper)
    proj = subject.rig.project(model.marker_positions(truth))  # (T, V, M + 1, 2)
    width, height = subject.frame_size
    for v, view in enumerate(subject.rig.views):
        x, y, w, h = view.roi if view.roi is not None else (0, 0, width, height)
        u, vv = proj[:, v, :, 0], proj[:, v, :, 1]
        assert np.all(np.isfinite(proj[:, v]))
        assert u.min() >= x + MARGIN_PX and u.max() <= x + w - MARGIN_PX, view.name
        assert vv.min() >= y + MARGIN_PX and vv.max() <= y + h - MARGIN_PX, view.name
    if name == "hexapod":  # walking is smooth (the others jump on purpose: kicks, new passes)
        assert np.abs(np.diff(truth, axis=0)).max() < 30.0


def test_hexapod_camera_subsets_are_views_of_the_six():
    six = load("hexapod", 6).rig
    for cameras, views in HEXAPOD_CAMERAS.items():
        rig = load("hexapod", cameras).rig
        assert rig.n_videos == cameras
        assert [v.projection for v in rig.views] == [six.views[i].projection for i in views]


def test_load_refuses_unknown_subjects_and_cameras():
    with pytest.raises(ValueError, match="subject"):
        load("spider")
    with pytest.raises(ValueError, match="camera"):
        load("biped", 3)
