"""Camera rig: parsing and validation (FORMATS §2), the three projections against hand results and OpenCV."""

from __future__ import annotations

import copy
import json
import math

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from core.examples import LOCUST
from core.rig import Rig, RigError

EXAMPLE = LOCUST / "rig.json"

AFFINE = {"type": "affine", "matrix": [[3.0, 0, 0, 240], [0, -3.0, 0, 184]]}
PINHOLE = {"type": "pinhole", "K": [[800.0, 0, 320], [0, 700.0, 240], [0, 0, 1]],
           "dist": [0.01, -0.02, 0.001, 0.002, 0.003], "rvec": [0.1, -0.2, 0.05], "tvec": [0.3, -0.1, 5.0]}
DLT = {"type": "matrix", "P": [[2.0, 0, 0, 1], [0, 3.0, 0, 2], [0, 0, 1.0, 4]]}


def _rig(*projections: dict, **view: object) -> Rig:
    views = [{"name": f"v{i}", "projection": p, **view} for i, p in enumerate(projections)]
    return Rig.from_dict({"views": views})


def _pinhole(K: np.ndarray, dist: np.ndarray, rvec: np.ndarray, tvec: np.ndarray) -> dict:
    return {"type": "pinhole", "K": K.tolist(), "dist": dist.tolist(), "rvec": rvec.tolist(),
            "tvec": tvec.tolist()}


# ---- parsing ---------------------------------------------------------------------------------


def test_parse_locust_example():
    rig = Rig.from_json(EXAMPLE)
    assert [v.name for v in rig.views] == ["side", "top"]
    assert [v.video for v in rig.views] == [0, 0]
    assert [v.roi for v in rig.views] == [(0, 0, 360, 288), (0, 288, 360, 288)]
    assert rig.n_videos == 1
    assert rig.views[1].projection == {"type": "affine", "matrix": [[3.0, 0, 0, 240], [0, 0, 3.0, 438]]}


def test_affine_by_hand():
    """side: (u, v) = (3x + 240, -3y + 184); top: (3x + 240, 3z + 438)."""
    rig = Rig.from_json(EXAMPLE)
    got = rig.project(np.array([[1.0, 2.0, 3.0], [0.0, 0.0, 0.0]]))
    np.testing.assert_array_equal(got, [[(243, 178), (240, 184)], [(243, 447), (240, 438)]])


def test_defaults_and_json_round_trip():
    rig = Rig.from_json(json.dumps({"views": [
        {"projection": AFFINE}, {"name": "cam", "video": 2, "roi": [1, 2, 3, 4], "projection": PINHOLE},
        {"name": "dlt", "video": 1, "projection": DLT},
    ]}))
    assert [v.name for v in rig.views] == ["view0", "cam", "dlt"]
    assert [v.video for v in rig.views] == [0, 2, 1] and rig.n_videos == 3
    assert [v.roi for v in rig.views] == [None, (1, 2, 3, 4), None]
    assert Rig.from_json(rig.to_json()) == rig
    assert Rig.from_json(rig.to_json().encode()) == rig


def test_project_shapes():
    rig = _rig(AFFINE, DLT)
    pts = np.arange(12.0).reshape(4, 3)
    one, many = rig.project(pts), rig.project(np.stack([pts, pts + 1, pts]))
    assert one.shape == (2, 4, 2) and many.shape == (3, 2, 4, 2)
    np.testing.assert_array_equal(many[0], one)
    np.testing.assert_array_equal(many[2], one)


@pytest.mark.parametrize("shape", [(3,), (4, 2), (2, 4, 4), (1, 1, 1, 3)])
def test_project_wrong_shape(shape):
    with pytest.raises(ValueError, match=r"points must have shape \(M, 3\) or \(T, M, 3\)"):
        _rig(AFFINE).project(np.zeros(shape))


# ---- pinhole = OpenCV projectPoints ----------------------------------------------------------------


@pytest.mark.parametrize("n_dist", [0, 4, 5, 8])
@pytest.mark.parametrize("seed", range(5))
def test_pinhole_matches_opencv(n_dist, seed):
    rng = np.random.default_rng(100 * n_dist + seed)
    fx, fy = rng.uniform(200, 2000, 2)
    K = np.array([[fx, 0, rng.uniform(100, 900)], [0, fy, rng.uniform(100, 700)], [0, 0, 1]])
    dist = rng.uniform(-0.2, 0.2, n_dist) * ([1, 1, 0.05, 0.05, 1, 1, 1, 1][:n_dist])
    rvec, tvec = rng.uniform(-np.pi / 2, np.pi / 2, 3), rng.uniform(-2, 2, 3)
    # Points in front of the camera: camera coordinates first, then back to the world.
    cam = np.column_stack([rng.uniform(-1, 1, (20, 2)), rng.uniform(2, 8, 20)])
    R, _ = cv2.Rodrigues(rvec)
    world = (cam - tvec) @ R  # R^T (cam - t), row-wise
    expected, _ = cv2.projectPoints(world, rvec, tvec, K, dist if n_dist else None)
    got = _rig(_pinhole(K, dist, rvec, tvec)).project(world)[0]
    np.testing.assert_allclose(got, expected.reshape(-1, 2), rtol=1e-12, atol=1e-9)


def test_pinhole_by_hand():
    """Identity pose, no distortion: u = fx·x/z + cx, v = fy·y/z + cy."""
    K = np.array([[100.0, 0, 50], [0, 200.0, 60], [0, 0, 1]])
    rig = _rig(_pinhole(K, np.zeros(0), np.zeros(3), np.array([0.0, 0.0, 1.0])))
    np.testing.assert_allclose(rig.project(np.array([[1.0, -1.0, 1.0]]))[0], [(100, -40)], atol=1e-12)


@pytest.mark.parametrize("z", [-1.0, -1e-9, 0.0])
def test_point_behind_pinhole_is_far_and_finite(z):
    K = np.array([[100.0, 0, 50], [0, 100.0, 50], [0, 0, 1]])
    rig = _rig(_pinhole(K, np.array([0.1, 0.0, 0.0, 0.0]), np.zeros(3), np.zeros(3)))
    got = rig.project(np.array([[0.5, 0.5, z], [0.0, 0.0, 1.0]]))[0]
    assert np.all(np.isfinite(got))
    assert np.all(np.abs(got[0]) > 1e6)
    np.testing.assert_allclose(got[1], [50, 50], atol=1e-12)


@settings(max_examples=100, deadline=None)
@given(
    st.lists(st.floats(-3, 3), min_size=3, max_size=3),
    st.lists(st.floats(-5, 5), min_size=3, max_size=3),
    st.floats(10, 5000), st.floats(10, 5000), st.floats(-1000, 1000), st.floats(-1000, 1000),
    st.floats(0.01, 1000),
    st.sampled_from([0, 4, 5, 8]),
)
def test_optical_axis_lands_on_principal_point(rvec, tvec, fx, fy, cx, cy, depth, n_dist):
    """Camera point (0, 0, d) → (cx, cy) whatever the pose; distortion is 0 on the axis."""
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]])
    rvec, tvec = np.array(rvec), np.array(tvec)
    R, _ = cv2.Rodrigues(rvec)
    world = R.T @ (np.array([0.0, 0.0, depth]) - tvec)
    dist = np.full(n_dist, 0.3)
    got = _rig(_pinhole(K, dist, rvec, tvec)).project(world[None])[0, 0]
    # Rounding in R^T (…) leaves ~1e-15 of the (|t| + d) scale off the axis; scaled by f/d in pixels.
    tol = 1e-12 * max(fx, fy) * (1 + (np.abs(tvec).sum() + depth) / depth)
    np.testing.assert_allclose(got, [cx, cy], rtol=0, atol=tol)


# ---- DLT ------------------------------------------------------------------------------------------


def test_dlt_by_hand():
    """P X for X = (1, 1, 1, 1) is (3, 5, 5): (u, v) = (0.6, 1.0)."""
    np.testing.assert_allclose(_rig(DLT).project(np.array([[1.0, 1.0, 1.0]]))[0], [(0.6, 1.0)], atol=1e-15)


def test_dlt_matches_homogeneous_division():
    rng = np.random.default_rng(7)
    P = rng.normal(size=(3, 4))
    P[2, 3] = 50.0  # keeps p3·X away from 0 for the sample points
    pts = rng.uniform(-5, 5, (10, 3))
    h = np.column_stack([pts, np.ones(10)]) @ P.T
    got = _rig({"type": "matrix", "P": P.tolist()}).project(pts)[0]
    np.testing.assert_allclose(got, h[:, :2] / h[:, 2:], rtol=1e-13, atol=1e-12)


def test_dlt_point_at_infinity_is_finite():
    got = _rig(DLT).project(np.array([[0.0, 0.0, -4.0]]))[0]  # p3·X = 0
    assert np.all(np.isfinite(got)) and np.all(np.abs(got) > 1e6)


# ---- validation: one case per branch, each naming the view and the problem -------------------------


def _doc(
    view_changes: dict | None = None, projection_changes: dict | None = None, base: dict = PINHOLE
) -> dict:
    projection = {**copy.deepcopy(base), **(projection_changes or {})}
    projection = {k: v for k, v in projection.items() if v is not DROP}
    view = {"name": "cam", "video": 0, "projection": projection, **(view_changes or {})}
    return {"views": [{k: v for k, v in view.items() if v is not DROP}]}


DROP = object()
K_OK = PINHOLE["K"]

INVALID_DICT = {
    "not_an_object": ([1, 2], "rig must be an object with a list 'views'"),
    "views_not_a_list": ({"views": {"name": "cam"}}, "rig must be an object with a list 'views'"),
    "no_views": ({"views": []}, "rig has no views"),
    "view_not_an_object": ({"views": ["cam"]}, "view 0 must be an object"),
    "empty_name": (_doc({"name": ""}), "view 0: 'name' must be a non-empty string"),
    "name_not_a_string": (_doc({"name": 3}), "view 0: 'name' must be a non-empty string"),
    "duplicate_name": ({"views": [_doc()["views"][0], _doc()["views"][0]]}, "duplicate view name 'cam'"),
    "negative_video": (_doc({"video": -1}),
                       "view 'cam': 'video' must be a non-negative integer index, got -1"),
    "fractional_video": (_doc({"video": 1.5}), "view 'cam': 'video' must be a non-negative integer"),
    "boolean_video": (_doc({"video": True}), "view 'cam': 'video' must be a non-negative integer"),
    "string_video": (_doc({"video": "0"}), "view 'cam': 'video' must be a non-negative integer"),
    "roi_negative": (_doc({"roi": [-1, 0, 10, 10]}), r"view 'cam': roi must be \[x, y, width, height\]"),
    "roi_zero_size": (_doc({"roi": [0, 0, 0, 10]}), r"view 'cam': roi must be \[x, y, width, height\]"),
    "roi_fractional": (_doc({"roi": [0, 0.5, 10, 10]}), r"view 'cam': roi must be \[x, y, width, height\]"),
    "roi_length": (_doc({"roi": [0, 0, 10]}), "view 'cam' roi must have shape 4, got"),
    "roi_not_numbers": (_doc({"roi": ["0", "0", "10", "10"]}), "view 'cam' roi must be a 4 array of numbers"),
    "roi_boolean": (_doc({"roi": [True, 0, 10, 10]}), "view 'cam' roi must be a 4 array of numbers"),
    "no_projection": (_doc({"projection": DROP}), "view 'cam': 'projection' must be an object with type"),
    "unknown_type": (_doc(projection_changes={"type": "fisheye"}),
                     "view 'cam': 'projection' must be an object"),
    "affine_missing_matrix": (_doc(base={"type": "affine"}), "view 'cam' affine matrix must be a 2×4 array"),
    "affine_wrong_shape": (_doc(base={"type": "affine", "matrix": [[1, 0, 0], [0, 1, 0]]}),
                           "view 'cam' affine matrix must have shape 2×4, got"),
    "affine_ragged": (_doc(base={"type": "affine", "matrix": [[1, 0, 0, 0], [0, 1]]}),
                      "view 'cam' affine matrix must be a 2×4 array"),
    "affine_strings": (_doc(base={"type": "affine", "matrix": [["3", 0, 0, 1], [0, 3, 0, 0]]}),
                       "view 'cam' affine matrix must be a 2×4 array of numbers"),
    "affine_singular": (_doc(base={"type": "affine", "matrix": [[1, 2, 3, 0], [2, 4, 6, 5]]}),
                        "view 'cam': affine matrix is singular"),
    "affine_nan": (_doc(base={"type": "affine", "matrix": [[math.nan, 0, 0, 0], [0, 1, 0, 0]]}),
                   "view 'cam' affine matrix contains a value that is not a finite number"),
    "matrix_missing_P": (_doc(base={"type": "matrix"}), "view 'cam' P must be a 3×4 array"),
    "matrix_singular": (_doc(base={"type": "matrix", "P": [[1, 0, 0, 0], [0, 1, 0, 0], [1, 1, 0, 1]]}),
                        "view 'cam': P is singular"),
    "K_missing": (_doc(projection_changes={"K": DROP}), "view 'cam' K must be a 3×3 array"),
    "K_zero_focal": (_doc(projection_changes={"K": [[0, 0, 1], [0, 1, 1], [0, 0, 1]]}),
                     r"view 'cam': K must be \[\[fx, 0, cx\]"),
    "K_negative_fy": (_doc(projection_changes={"K": [[1, 0, 1], [0, -1, 1], [0, 0, 1]]}),
                      r"view 'cam': K must be \[\[fx, 0, cx\]"),
    "K_lower_triangle": (_doc(projection_changes={"K": [[1, 0, 1], [0.5, 1, 1], [0, 0, 1]]}),
                         r"view 'cam': K must be \[\[fx, 0, cx\]"),
    "K_last_row": (_doc(projection_changes={"K": [[1, 0, 1], [0, 1, 1], [0, 0, 2]]}),
                   r"view 'cam': K must be \[\[fx, 0, cx\]"),
    "K_skew": (_doc(projection_changes={"K": [[800, 5, 320], [0, 700, 240], [0, 0, 1]]}),
               r"view 'cam': K must be .* \(no skew\)"),
    "dist_length": (_doc(projection_changes={"dist": [0.1, 0.2, 0.3]}),
                    "view 'cam': dist must be a list of 0, 4, 5 or 8 coefficients .* got 3"),
    "dist_not_a_list": (_doc(projection_changes={"dist": 0.1}),
                        "view 'cam': dist must be a list of 0, 4, 5 or 8 coefficients .* got 0.1"),
    "dist_null": (_doc(projection_changes={"dist": None}),
                  "view 'cam': dist must be a list of 0, 4, 5 or 8 coefficients .* got None"),
    "dist_strings": (_doc(projection_changes={"dist": ["a", "b", "c", "d"]}),
                     "view 'cam' dist must be a 4 array of numbers"),
    "rvec_missing": (_doc(projection_changes={"rvec": DROP}), "view 'cam' rvec must be a 3 array"),
    "tvec_wrong_shape": (_doc(projection_changes={"tvec": [0, 0]}), "view 'cam' tvec must have shape 3, got"),
}


def test_validation_cases_start_from_a_valid_rig():
    rig = Rig.from_dict(_doc())
    assert rig.views[0].projection["dist"] == PINHOLE["dist"]


@pytest.mark.parametrize(("doc", "match"), INVALID_DICT.values(), ids=INVALID_DICT.keys())
def test_invalid_rig(doc, match):
    with pytest.raises(RigError, match=match):
        Rig.from_dict(doc)


GOOD_JSON = json.dumps(_doc(base=AFFINE))
INVALID_JSON = {
    "not_json": ("views: [side, top]", "rig is not valid JSON"),
    "truncated": (GOOD_JSON[:-5], "rig is not valid JSON"),
    "nan_literal": (GOOD_JSON.replace("240", "NaN", 1), "rig contains NaN, which is not a number"),
    "infinity_literal": (GOOD_JSON.replace("240", "-Infinity", 1), "rig contains -Infinity"),
    "overflow": (GOOD_JSON.replace("240", "1e400", 1), "affine matrix contains a value that is not a finite"),
    "not_utf8": (b'{"views": "\xff"}', "cannot read rig file"),
}


@pytest.mark.parametrize(("text", "match"), INVALID_JSON.values(), ids=INVALID_JSON.keys())
def test_invalid_rig_json(text, match):
    with pytest.raises(RigError, match=match):
        Rig.from_json(text)


def test_unreadable_rig_file(tmp_path):
    with pytest.raises(RigError, match="cannot read rig file"):
        Rig.from_json(tmp_path / "missing.json")


def test_numpy_values_accepted_from_python_callers():
    rig = Rig.from_dict({"views": [{"name": "c", "projection": {
        "type": "pinhole", "K": np.array(K_OK), "dist": np.zeros(4), "rvec": (0.0, 0.0, 0.0),
        "tvec": [np.float64(0.0), np.int64(0), 5]}}]})
    assert rig.views[0].projection["tvec"] == [0.0, 0.0, 5.0]
