"""Make the aniposelib fixtures of ``tests/core/test_calibration.py``.

Written by the real aniposelib (``CameraGroup.dump``), which is not a test dependency
(it pulls in jax and a second OpenCV build), so the files are committed:

    python3 -m venv /tmp/anipose && /tmp/anipose/bin/pip install aniposelib==0.8.0
    /tmp/anipose/bin/python tests/data/make_anipose_fixture.py

- ``anipose_calibration.toml``: three pinhole cameras around the origin (model units: mm),
  with 5, 4 and 5 distortion coefficients;
- ``anipose_projections.json``: 50 random points in front of them and their projections
  by aniposelib's ``CameraGroup.project`` (shape cameras × points × 2, pixels), the
  reference our importer must reproduce to 1e-6 px;
- ``anipose_fisheye.toml``: one fisheye camera, which rig.json cannot represent.
"""

import json
from pathlib import Path

import numpy as np
from aniposelib.cameras import Camera, CameraGroup, FisheyeCamera

HERE = Path(__file__).parent


def camera(name: str, f: float, cx: float, cy: float, dist: list[float], rvec: list[float],
           tvec: list[float]) -> Camera:
    matrix = [[f, 0.0, cx], [0.0, f * 1.01, cy], [0.0, 0.0, 1.0]]
    return Camera(matrix=matrix, dist=dist, size=(1280, 1024), rvec=rvec, tvec=tvec, name=name)


def main() -> None:
    group = CameraGroup([
        camera("left", 1500.0, 641.3, 509.8, [-0.21, 0.13, 0.0012, -0.0008, -0.02],
               [0.05, 0.42, -0.03], [-60.0, 5.0, 400.0]),
        camera("front", 1420.0, 633.0, 515.2, [0.08, -0.05, 0.0003, 0.0011],
               [-0.02, -0.01, 0.015], [3.0, -4.0, 380.0]),
        camera("right", 1555.5, 650.1, 500.4, [-0.11, 0.02, -0.0005, 0.0002, 0.004],
               [0.03, -0.45, 0.02], [62.0, 2.0, 410.0]),
    ])
    group.dump(str(HERE / "anipose_calibration.toml"))
    rng = np.random.default_rng(16)
    points = rng.uniform([-40, -30, -20], [40, 30, 40], size=(50, 3))
    projected = group.project(points)
    (HERE / "anipose_projections.json").write_text(json.dumps(
        {"points": points.tolist(), "projected": projected.tolist()}) + "\n")
    fisheye = CameraGroup([FisheyeCamera(matrix=[[800.0, 0, 640], [0, 800.0, 512], [0, 0, 1]],
                                         dist=[0.1, 0.01, 0.0, 0.0], size=(1280, 1024),
                                         rvec=[0, 0, 0], tvec=[0, 0, 300], name="wide")])
    fisheye.dump(str(HERE / "anipose_fisheye.toml"))
    print(f"wrote the anipose fixtures to {HERE}")


if __name__ == "__main__":
    main()
