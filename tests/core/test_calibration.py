"""Calibration import (core.calibration): each format against the tool that writes it."""

from __future__ import annotations

import json
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from core.calibration import OPENCV_TO_OURS_PX, from_anipose, from_dlt, from_opencv, import_rig
from core.rig import RigError

DATA = Path(__file__).parents[1] / "data"


# ---- Anipose ---------------------------------------------------------------------------------


def test_anipose_projects_as_aniposelib_does():
    """Fixture and projections written by aniposelib 0.8.0 (tests/data/make_anipose_fixture.py).

    aniposelib's pixel centres are OpenCV's, at whole numbers; ours at +0.5.
    """
    rig = from_anipose(DATA / "anipose_calibration.toml")
    reference = json.loads((DATA / "anipose_projections.json").read_text())
    ours = rig.project(np.array(reference["points"]))
    assert [v.name for v in rig.views] == ["left", "front", "right"]
    assert [v.video for v in rig.views] == [0, 1, 2]
    assert [len(v.projection["dist"]) for v in rig.views] == [5, 4, 5]
    assert np.max(np.abs(ours - OPENCV_TO_OURS_PX - np.array(reference["projected"]))) < 1e-6


def test_opencv_principal_point_moves_half_a_pixel():
    """OpenCV's centre of the top-left pixel (0, 0) is our (0.5, 0.5): a point on the optical
    axis images at OpenCV's (cx, cy), at our (cx + 0.5, cy + 0.5)."""
    rig = import_rig("anipose", [ANIPOSE_CAMERA])
    assert rig.views[0].projection["K"] == [[800.0, 0.0, 320.5], [0.0, 800.0, 240.5], [0.0, 0.0, 1.0]]
    np.testing.assert_allclose(rig.project(np.array([[0.0, 0.0, 0.0]])), [[[320.5, 240.5]]])


def test_anipose_video_indices_are_given_per_view():
    rig = from_anipose(DATA / "anipose_calibration.toml", videos=[0, 1, 0])
    assert [v.video for v in rig.views] == [0, 1, 0]
    with pytest.raises(RigError, match="3 cameras but 2 video indices"):
        from_anipose(DATA / "anipose_calibration.toml", videos=[0, 1])


ANIPOSE_CAMERA = """[cam_0]
name = "a"
size = [640, 480]
matrix = [[800.0, 0.0, 320.0], [0.0, 800.0, 240.0], [0.0, 0.0, 1.0]]
distortions = [0.1, 0.0, 0.0, 0.0, 0.0]
rotation = [0.0, 0.0, 0.0]
translation = [0.0, 0.0, 100.0]
"""


@pytest.mark.parametrize(("text", "message"), [
    ("[cam_0\nname = 1", "calibration.toml: not valid TOML"),
    ("[metadata]\n", "no camera table"),
    (ANIPOSE_CAMERA.replace("rotation = [0.0, 0.0, 0.0]\n", ""),
     r"camera 'a' \[cam_0\] has no 'rotation'"),
    (ANIPOSE_CAMERA.replace("[0.1, 0.0, 0.0, 0.0, 0.0]", "[0.1, 0.2]"),
     "distortions must be a list of 0, 4, 5 or 8"),
    (ANIPOSE_CAMERA.replace("[0.0, 0.0, 100.0]", '[0.0, "x", 100.0]'),
     "translation must be a 3 array of numbers"),
    (ANIPOSE_CAMERA.replace("[0.0, 800.0, 240.0]", "[5.0, 800.0, 240.0]"), "K must be .*no skew"),
    (ANIPOSE_CAMERA + "fisheye = true\n", "camera 'a' \\[cam_0\\] is a fisheye camera"),
])
def test_anipose_malformed_file_is_one_clear_error(text, message):
    with pytest.raises(RigError, match=message) as info:
        import_rig("anipose", [text], labels=["calibration.toml"])
    assert "\n" not in str(info.value)


def test_anipose_fisheye_written_by_aniposelib_is_refused():
    with pytest.raises(RigError, match=r"anipose_fisheye.toml: camera 'wide' \[cam_0\] is a fisheye camera"):
        from_anipose(DATA / "anipose_fisheye.toml")


# ---- OpenCV FileStorage ------------------------------------------------------------------------


def _camera(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    K = np.array([[900.0 + 50 * seed, 0, 640.5], [0, 905.0 + 50 * seed, 480.25], [0, 0, 1]])
    dist = np.array([-0.2, 0.05, 0.001, -0.002, 0.01]) * rng.uniform(0.5, 1.5)
    return K, dist, rng.uniform(-0.3, 0.3, 3), np.array([0.0, 0.0, 300.0]) + rng.uniform(-20, 20, 3)


def _write(fs: cv2.FileStorage, prefix: str, K, dist, rvec, tvec, *, matrix_rotation: bool) -> None:
    fs.write(f"{prefix}camera_matrix", K)
    fs.write(f"{prefix}distortion_coefficients", dist.reshape(1, -1))
    if matrix_rotation:
        fs.write(f"{prefix}R", cv2.Rodrigues(rvec)[0])
        fs.write(f"{prefix}T", tvec.reshape(3, 1))
    else:
        fs.write(f"{prefix}rvec", rvec.reshape(3, 1))
        fs.write(f"{prefix}tvec", tvec.reshape(3, 1))


def _reference(cameras, points: np.ndarray) -> np.ndarray:
    """cv2.projectPoints: OpenCV's pixel coordinates (centres at whole numbers)."""
    return np.stack([cv2.projectPoints(points, rvec, tvec, K, dist)[0].reshape(-1, 2)
                     for K, dist, rvec, tvec in cameras])


@pytest.mark.parametrize("suffix", [".yml", ".xml"])
def test_opencv_files_one_camera_each_project_as_opencv(tmp_path, suffix):
    cameras = [_camera(0), _camera(1)]
    paths = []
    for i, cam in enumerate(cameras):
        path = tmp_path / f"cam{i}{suffix}"
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
        _write(fs, "", *cam, matrix_rotation=i == 1)
        fs.release()
        paths.append(path)
    rig = from_opencv(paths)
    points = np.random.default_rng(3).uniform(-30, 30, (40, 3))
    assert [v.name for v in rig.views] == ["cam0", "cam1"]
    assert np.max(np.abs(rig.project(points) - 0.5 - _reference(cameras, points))) < 1e-6


def test_opencv_file_with_named_cameras(tmp_path):
    cameras = [_camera(2), _camera(3), _camera(4)]
    path = tmp_path / "rig.yaml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for name, cam in zip(["top", "side", "front"], cameras, strict=True):
        fs.startWriteStruct(name, cv2.FileNode_MAP)
        _write(fs, "", *cam, matrix_rotation=name == "side")
        fs.endWriteStruct()
    fs.release()
    rig = import_rig("opencv", [path], videos=[0, 0, 1])
    points = np.random.default_rng(4).uniform(-30, 30, (40, 3))
    assert [(v.name, v.video) for v in rig.views] == [("top", 0), ("side", 0), ("front", 1)]
    assert np.max(np.abs(rig.project(points) - 0.5 - _reference(cameras, points))) < 1e-6


OPENCV_CAMERA = """%YAML:1.0
---
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 800., 0., 320., 0., 800., 240., 0., 0., 1. ]
rvec: [ 0., 0., 0. ]
tvec: [ 0., 0., 100. ]
"""


@pytest.mark.parametrize(("text", "message"), [
    ("camera_matrix: [", "cam.yml: not an OpenCV FileStorage YAML/XML file \\(Bad argument: Unsupported"),
    ("<?xml version='1.0'?><opencv_storage><K>1 2</opencv_storage>",
     "not an OpenCV FileStorage YAML/XML file \\(Parsing error: Mismatched closing tag\\)"),
    ("%YAML:1.0\nfoo: 1\n", "cam.yml: no camera: expected a camera matrix node"),
    (OPENCV_CAMERA.replace("tvec: [ 0., 0., 100. ]\n", ""),
     "camera 'cam': needs a rotation .* and a translation"),
    (OPENCV_CAMERA.replace("rvec: [ 0., 0., 0. ]", "R: [ 1., 2., 3., 4. ]"), "R must have shape 3×3"),
    (OPENCV_CAMERA.replace("rvec: [ 0., 0., 0. ]", "rvec: [ 0., zero, 0. ]"),
     "node 'rvec' must hold numbers"),
    (OPENCV_CAMERA + "D: [ 0.1, 0.2 ]\n", "distortion must be a list of 0, 4, 5 or 8 coefficients"),
    (OPENCV_CAMERA.replace("rows: 3", "rows: 300"), "node 'camera_matrix' is 300×3; at most 16 values"),
])
def test_opencv_malformed_file_is_one_clear_error(text, message):
    with pytest.raises(RigError, match=message) as info:
        import_rig("opencv", [text], labels=["cam.yml"])
    assert "\n" not in str(info.value) and "/io/" not in str(info.value)


# ---- DLTdv / Argus -----------------------------------------------------------------------------


def _our_P(seed: int) -> np.ndarray:
    """A camera's 3×4 P in our convention (top-left origin, v down, centres at +0.5)."""
    K, _, rvec, tvec = _camera(seed)
    K[0, 1] = 2.5  # DLT allows skew
    return K @ np.hstack([cv2.Rodrigues(rvec)[0], tvec.reshape(3, 1)])


def _dltdv_coefficients(P: np.ndarray, height: float) -> np.ndarray:
    """DLTdv's 11 coefficients of our P: bottom-left origin, y up, pixel centres at 1, 2, …"""
    to_dltdv = np.array([[1.0, 0.0, 0.5], [0.0, -1.0, height + 0.5], [0.0, 0.0, 1.0]])
    L = to_dltdv @ P
    return (L / L[2, 3]).ravel()[:11]


@pytest.mark.parametrize("layout", ["columns", "rows"])
def test_dlt_coefficients_round_trip(tmp_path, layout):
    heights = [960.0, 720.0]
    Ps = [_our_P(5), _our_P(6)]
    coefs = np.array([_dltdv_coefficients(P, h) for P, h in zip(Ps, heights, strict=True)])
    path = tmp_path / "cal_dltCoefs.csv"
    np.savetxt(path, coefs.T if layout == "columns" else coefs, delimiter=",", fmt="%.17g")
    rig = from_dlt(path, heights=heights)
    points = np.random.default_rng(7).uniform(-30, 30, (40, 3))
    X = np.hstack([points, np.ones((40, 1))])
    expected = np.stack([(X @ P.T)[:, :2] / (X @ P.T)[:, 2:] for P in Ps])
    assert [v.name for v in rig.views] == ["cam1", "cam2"]
    assert np.max(np.abs(rig.project(points) - expected)) < 1e-6


def test_dlt_pixel_convention():
    """DLTdv's centre of the top-left pixel, (1, height), is our (0.5, 0.5); (x, 1) is v = height - 0.5."""
    height = 480.0
    # Coefficients that image the world point (x, y, 0) at DLTdv's (x, y): (X, Y) / (Z + 1).
    coefs = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]
    rig = import_rig("dlt", ["\n".join(str(c) for c in coefs)], heights=[height])
    got = rig.project(np.array([[1.0, height, 0.0], [10.0, 1.0, 0.0]]))[0]
    np.testing.assert_allclose(got, [[0.5, 0.5], [9.5, height - 0.5]], atol=1e-12)


@pytest.mark.parametrize(("text", "heights", "message"), [
    ("1,2\n3,4\n", [480], "must be 11 rows \\(one column per camera\\) or 11 columns .* got 2×2"),
    ("1\n2\nx\n" + "4\n" * 8, [480], "DLT coefficients must be numbers"),
    ("1,2\n3\n", [480], "rows of different lengths"),
    ("", [480], "no DLT coefficients"),
    ("1\n" * 10 + "nan\n", [480], "not a finite number"),
    ("1,1\n" * 11, [480, 640, 720], "2 cameras but 3 image heights"),
    ("1\n0\n0\n0\n0\n1\n0\n0\n0\n0\n0\n", [-1], "image heights must be numbers of pixels > 0"),
    ("1\n" * 11, None, "give each camera's image height"),
])
def test_dlt_malformed_file_is_one_clear_error(text, heights, message):
    with pytest.raises(RigError, match=message):
        import_rig("dlt", [text], labels=["coefs.csv"], heights=heights)


def test_dlt_singular_matrix_is_refused_by_the_rig():
    with pytest.raises(RigError, match=r"coefs\.csv: view 'cam1': P is singular"):
        import_rig("dlt", ["0\n" * 11], labels=["coefs.csv"], heights=[480])


def test_unknown_format_and_sizes():
    with pytest.raises(RigError, match="unknown calibration format 'vicon'"):
        import_rig("vicon", ["x"])
    with pytest.raises(RigError, match="larger than"):
        import_rig("anipose", ["#" * (2**20 + 1)])
    with pytest.raises(RigError, match="only needed for DLT"):
        import_rig("anipose", [ANIPOSE_CAMERA], heights=[480])


# ---- hostile files: one RigError, fast, never a crash ---------------------------------------------

DEEP = 100_000  # OpenCV's parsers crash the process (SIGSEGV) near 50,000 levels


@pytest.mark.parametrize(("fmt", "text", "message"), [
    ("anipose", "[cam_0]\nmatrix = " + "9" * 100_000 + "\n", "not valid TOML: Exceeds the limit"),
    ("anipose", "".join(f"[c{i}]\n" for i in range(100_000)), "100000 tables; at most 256"),
    ("anipose", "a = " + "[" * 300_000 + "]" * 300_000, "TOML nested too deeply"),
    ("dlt", "1" * 200_000, "not a CSV of DLT coefficients"),
    ("opencv", "<?xml version='1.0'?><opencv_storage>" + "<a>" * DEEP + "</a>" * DEEP + "</opencv_storage>",
     "nested 100001 levels deep"),
    ("opencv", "%YAML:1.0\na: " + "[" * DEEP + "]" * DEEP, "nested 100000 levels deep"),
    ("opencv", '{"a": ' + "{" * DEEP + "}" * DEEP + "}", "nested 100001 levels deep"),
    ("opencv", "%YAML:1.0\n" + "".join(" " * i + "b:\n" for i in range(1400)), "nested 1399 levels deep"),
    ("opencv", b"\xff\xfe\x00", "not UTF-8 text"),
])
def test_hostile_calibration_is_refused_fast(fmt, text, message):
    t0 = time.perf_counter()
    with pytest.raises(RigError, match=message):
        import_rig(fmt, [text], labels=["f"], heights=[480] if fmt == "dlt" else None)
    assert time.perf_counter() - t0 < 1.0
