"""POST /v1/rigs/import: another tool's calibration stored as a rig, through HTTP."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

pytestmark = [pytest.mark.service]

DATA = Path(__file__).parents[1] / "data"
DEEP_XML = b"<?xml version='1.0'?><opencv_storage>%s%s</opencv_storage>" % (b"<a>" * 10**5, b"</a>" * 10**5)


@pytest.fixture(scope="module")
def client(embedded):
    return embedded.create_lab("calibrations")


def _files(*named: tuple[str, bytes]) -> list[tuple[str, tuple[str, bytes]]]:
    return [("file", (name, data)) for name, data in named]


def test_anipose_calibration_becomes_a_rig(client):
    toml = (DATA / "anipose_calibration.toml").read_bytes()
    response = client.post("/rigs/import", params={"format": "anipose", "video_index": [0, 1, 1]},
                           files=_files(("calibration.toml", toml)))
    assert response.status_code == 201, response.text
    rig = response.json()
    assert rig["views"] == ["left", "front", "right"] and rig["videos"] == 2
    assert client.get(f"/rigs/{rig['id']}").json() == rig


def test_opencv_files_one_per_camera(client, tmp_path):
    files = []
    for i in range(2):
        path = tmp_path / f"cam{i}.yml"
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
        fs.write("camera_matrix", np.array([[800.0, 0, 320], [0, 800.0, 240], [0, 0, 1]]))
        fs.write("rvec", np.array([[0.0], [0.1 * i], [0.0]]))
        fs.write("tvec", np.array([[0.0], [0.0], [100.0]]))
        fs.release()
        files.append((path.name, path.read_bytes()))
    response = client.post("/rigs/import", params={"format": "opencv"}, files=_files(*files))
    assert response.status_code == 201, response.text
    assert response.json()["views"] == ["cam0", "cam1"]


def test_dlt_needs_the_image_height(client):
    coefs = b"\n".join(str(c).encode() for c in [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1])
    refused = client.post("/rigs/import", params={"format": "dlt"}, files=_files(("c.csv", coefs)))
    assert refused.status_code == 422 and "image height" in refused.json()["detail"]
    response = client.post("/rigs/import", params={"format": "dlt", "height": 480},
                           files=_files(("c.csv", coefs)))
    assert response.status_code == 201, response.text
    assert response.json()["views"] == ["cam1"]


@pytest.mark.parametrize(("params", "files", "status", "detail"), [
    ({"format": "anipose"}, [("lab.toml", b"[cam_0\n")], 422, "lab.toml: not valid TOML"),
    ({"format": "anipose"}, [("wide.toml", (DATA / "anipose_fisheye.toml").read_bytes())], 422,
     "wide.toml: camera 'wide' [cam_0] is a fisheye camera"),
    ({"format": "opencv"}, [("cam.yml", b"%YAML:1.0\nfoo: 1\n")], 422, "cam.yml: no camera"),
    ({"format": "dlt", "height": 480}, [("c.csv", b"1,2\n3,4\n")], 422, "c.csv: DLT coefficients must be 11"),
    ({"format": "vicon"}, [("x", b"x")], 422, "format"),
    ({"format": "anipose"}, [], 422, "no file field named 'file'"),
    ({"format": "anipose"}, [("big.toml", b"#" * (2**20 + 10))], 413, "larger than"),
    # OpenCV's parser would crash the server process (SIGSEGV) on this one.
    ({"format": "opencv"}, [("deep.xml", DEEP_XML)], 422, "deep.xml: nested 100001 levels"),
])
def test_a_malformed_calibration_is_a_clear_4xx(client, params, files, status, detail):
    response = client.post("/rigs/import", params=params, files=_files(*files) or {"other": "x"})
    assert response.status_code == status, response.text
    assert detail in response.json()["detail"]
    assert "/tmp" not in response.text
    assert client.get("/rigs/1").status_code in (200, 404)  # the server is still up


def test_a_calibration_not_sent_as_multipart_is_422(client):
    response = client.post("/rigs/import", params={"format": "anipose"}, content=b"[cam_0]")
    assert response.status_code == 422 and "multipart/form-data" in response.json()["detail"]
