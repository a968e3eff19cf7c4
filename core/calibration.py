"""Camera calibrations of other tools imported as a rig (FORMATS §2).

Three formats, each read into :class:`core.rig.Rig` (conventions and conversions:
``docs/INTERCHANGE.md``):

- ``anipose``: aniposelib's / Anipose's / Pose2Sim's ``calibration.toml``, one table per
  camera (``name``, ``size``, ``matrix``, ``distortions``, ``rotation`` (Rodrigues),
  ``translation``): a ``pinhole`` view each (aniposelib projects with OpenCV's
  ``projectPoints``);
- ``opencv``: OpenCV ``FileStorage`` YAML or XML, one camera per file or several cameras
  as named maps (:data:`OPENCV_NODES` lists the node names read): a ``pinhole`` view each;
- ``dlt``: DLTdv's or Argus's 11 DLT coefficients per camera in a CSV (one column per
  camera, or one row): a ``matrix`` view each, its image origin moved from DLTdv's bottom
  left (v up, pixel centres at whole numbers from 1) to ours, which needs each image's height.

OpenCV's calibrations (and so aniposelib's, whose corners OpenCV detects) put pixel
centres at whole numbers; ours are at +0.5 (FORMATS §2). The principal point moves by
:data:`OPENCV_TO_OURS_PX` in u and v, which shifts every projection by exactly that.

Every file is bounded by :data:`core.rig.MAX_RIG_BYTES` and every mistake is one
:class:`~core.rig.RigError` naming the file, the camera and the problem.
"""

from __future__ import annotations

import csv
import io
import math
import re
import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from core._files import read_bounded
from core.rig import MAX_RIG_BYTES, MAX_VIEWS, Rig, RigError, _matrix

__all__ = [
    "FORMATS", "OPENCV_NODES", "OPENCV_TO_OURS_PX", "from_anipose", "from_dlt", "from_opencv", "import_rig",
]

FORMATS = ("anipose", "opencv", "dlt")

# Node names read from an OpenCV FileStorage camera, first match wins: what OpenCV's own
# samples (calibration.cpp: camera_matrix, distortion_coefficients), its Python tutorials
# (mtx/dist, rvec/tvec) and stereo code (K, D, R, T) write.
OPENCV_NODES = {
    "matrix": ("camera_matrix", "cameraMatrix", "K", "M", "mtx"),
    "dist": ("distortion_coefficients", "dist_coeffs", "distCoeffs", "D", "dist"),
    "rvec": ("rvec", "rotation_vector"),
    "R": ("R", "rotation_matrix"),
    "tvec": ("tvec", "T", "translation"),
}
# OpenCV's distortion vectors that a pinhole view holds (k1 k2 p1 p2 [k3 [k4 k5 k6]]); 12 and
# 14 coefficients (thin prism, tilted sensor) have no place in rig.json.
DIST_LENGTHS = (0, 4, 5, 8)
_MAX_NODE_VALUES = 16
# Nesting levels (and indentation characters) of a FileStorage document: a camera needs 3
# (root, camera, matrix); OpenCV's parser crashes the process near 50,000 (see _filestorage).
MAX_FILESTORAGE_DEPTH = 64
# OpenCV's pixel (0, 0) is the centre of the top-left pixel, ours (0.5, 0.5).
OPENCV_TO_OURS_PX = 0.5  # a 3×3 matrix or a distortion vector: a larger node is not a camera's

Source = str | bytes | Path


def import_rig(
    fmt: str,
    sources: Sequence[Source],
    *,
    labels: Sequence[str] | None = None,
    heights: Sequence[float] | None = None,
    videos: Sequence[int] | None = None,
) -> Rig:
    """Import ``sources`` (file paths, or documents as text/bytes) of format ``fmt``.

    labels : how each source is named in messages (default: the file's name).
    heights : image height in pixels per DLT camera, or one for all (``dlt`` only).
    videos : the video index of each view, in the order of the views (default 0, 1, …).
    """
    if fmt not in FORMATS:
        raise RigError(f"unknown calibration format {fmt!r}; use one of {', '.join(FORMATS)}")
    if not sources:
        raise RigError("no calibration file given")
    names = list(labels) if labels is not None else [_label(s) for s in sources]
    if fmt != "dlt" and heights is not None:
        raise RigError("image heights are only needed for DLT coefficients (format dlt)")
    if fmt == "opencv":
        return from_opencv(sources, labels=names, videos=videos)
    if len(sources) != 1:
        raise RigError(f"format {fmt} takes one file, got {len(sources)}")
    if fmt == "anipose":
        return from_anipose(sources[0], label=names[0], videos=videos)
    if heights is None:
        raise RigError("DLT coefficients have their origin at the image's bottom left: "
                       "give each camera's image height in pixels (mocap rig import --height; "
                       "the API's height parameter)")
    return from_dlt(sources[0], heights=heights, label=names[0], videos=videos)


# ---- Anipose / aniposelib / Pose2Sim ----------------------------------------------------------


def from_anipose(source: Source, *, label: str | None = None, videos: Sequence[int] | None = None) -> Rig:
    """A rig from aniposelib's ``calibration.toml`` (``CameraGroup.dump``): a pinhole view
    per camera table, in file order, named by its ``name``.

    The ``[metadata]`` table is ignored; ``fisheye = true`` cameras are refused (OpenCV's
    fisheye model is not a rig.json projection).
    """
    label = label or _label(source)
    text = _text(source, label)
    # tomllib takes seconds for a megabyte of table headers (7 s for 100,000): count them first.
    headers = sum(line.lstrip().startswith("[") for line in text.splitlines())
    if headers > MAX_VIEWS + 1:
        raise RigError(f"{label}: {headers} tables; at most {MAX_VIEWS} cameras (MAX_VIEWS)")
    try:
        doc = tomllib.loads(text)
    except RecursionError:
        raise RigError(f"{label}: TOML nested too deeply") from None
    except ValueError as exc:  # TOMLDecodeError, and integers of more than 4300 digits
        raise RigError(f"{label}: not valid TOML: {str(exc)[:200]}") from None
    tables = [(key, value) for key, value in doc.items() if key != "metadata"]
    if not tables:
        raise RigError(f"{label}: no camera table (aniposelib writes [cam_0], [cam_1], …)")
    if len(tables) > MAX_VIEWS:
        raise RigError(f"{label}: {len(tables)} cameras; at most {MAX_VIEWS} (MAX_VIEWS)")
    views = [_anipose_view(key, table, label) for key, table in tables]
    return _rig(views, videos, label)


def _anipose_view(key: str, table: Any, label: str) -> dict[str, Any]:
    if not isinstance(table, dict):
        raise RigError(f"{label}: [{key}] must be a camera table, got a {type(table).__name__}")
    name = table.get("name", key)
    where = f"{label}: camera '{name}' [{key}]"
    if not isinstance(name, str) or not name:
        raise RigError(f"{label}: [{key}] 'name' must be a non-empty string")
    if table.get("fisheye", False):
        raise RigError(f"{where} is a fisheye camera; rig.json has no fisheye projection "
                       "(calibrate it with the pinhole model)")
    missing = [k for k in ("matrix", "distortions", "rotation", "translation") if k not in table]
    if missing:
        raise RigError(f"{where} has no '{missing[0]}'")
    dist = _vector(table["distortions"], where, "distortions")
    K = _matrix(table["matrix"], (3, 3), f"{where} matrix")
    return {"name": name, "projection": {
        "type": "pinhole", "K": _from_opencv_pixels(K).tolist(),
        "dist": dist.tolist(), "rvec": _matrix(table["rotation"], (3,), f"{where} rotation").tolist(),
        "tvec": _matrix(table["translation"], (3,), f"{where} translation").tolist()}}


# ---- OpenCV FileStorage -----------------------------------------------------------------------


def from_opencv(
    sources: Sequence[Source], *, labels: Sequence[str] | None = None, videos: Sequence[int] | None = None
) -> Rig:
    """A rig from OpenCV FileStorage YAML/XML files: a pinhole view per camera.

    A file whose top level holds a camera matrix node is one camera, named by its file
    (without suffix) or its string node ``name``; otherwise each top-level map holding a
    camera matrix node is a camera named by its key. Views follow the files' order, then
    the order within a file. Node names: :data:`OPENCV_NODES`; the rotation is ``rvec``
    (Rodrigues) or ``R`` (a 3×3 rotation, or a Rodrigues 3-vector); no distortion node
    means no distortion.
    """
    names = list(labels) if labels is not None else [_label(s) for s in sources]
    views: list[dict[str, Any]] = []
    for source, label in zip(sources, names, strict=True):
        storage = _filestorage(_text(source, label), label)  # its nodes live as long as it does
        root = storage.root()
        if _first(root, "matrix") is not None:
            name = root.getNode("name").string() if root.getNode("name").isString() else Path(label).stem
            views.append(_opencv_view(root, name or "camera", label))
            continue
        keys = root.keys()  # a FileNode method, not a dict's
        cameras = [k for k in keys if root.getNode(k).isMap() and _first(root.getNode(k), "matrix")]
        if not cameras:
            raise RigError(f"{label}: no camera: expected a camera matrix node "
                           f"({', '.join(OPENCV_NODES['matrix'])}) at the top level or in a named map")
        views.extend(_opencv_view(root.getNode(k), k, label) for k in cameras)
        if len(views) > MAX_VIEWS:
            raise RigError(f"{label}: more than {MAX_VIEWS} cameras (MAX_VIEWS)")
    return _rig(views, videos, ", ".join(names))


def _filestorage(text: str, label: str) -> Any:
    """A FileStorage document read from memory; OpenCV's parse error as one line.

    OpenCV's parsers recurse once per nesting level and overflow the C stack (the process
    dies: SIGSEGV) near 50,000 levels, so the nesting is measured first (:func:`_nesting`).
    """
    depth = _nesting(text)
    if depth > MAX_FILESTORAGE_DEPTH:
        raise RigError(f"{label}: nested {depth} levels deep; a calibration needs at most "
                       f"{MAX_FILESTORAGE_DEPTH}")
    try:
        return cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except (cv2.error, SystemError) as exc:
        raise RigError(f"{label}: not an OpenCV FileStorage YAML/XML file ({_cv_reason(exc)})") from None


def _nesting(text: str) -> int:
    """An upper bound on a YAML, JSON or XML document's nesting: the deepest of its bracket
    nesting (``[`` ``{``), its XML element nesting and its indentation in characters. Counts
    brackets and tags inside strings too: errs on the side of refusing."""
    raw = np.frombuffer(text.encode("utf-8", "replace"), dtype=np.uint8)
    if raw.size == 0:
        return 0
    b = {c: raw == ord(c) for c in "[]{}</>"}
    brackets = np.cumsum(b["["].astype(np.int64) + b["{"] - b["]"] - b["}"]).max()
    opens = b["<"][:-1] & ~np.isin(raw[1:], np.frombuffer(b"/?!", dtype=np.uint8))
    closes = (b["<"][:-1] & (raw[1:] == ord("/"))) | (b["/"][:-1] & b[">"][1:])
    tags = np.cumsum(opens.astype(np.int64) - closes).max() if opens.size else 0
    indent = max((len(line) - len(line.lstrip(" \t")) for line in text.splitlines()), default=0)
    return int(max(brackets, tags, indent))


def _cv_reason(exc: BaseException) -> str:
    """OpenCV's reason without its source paths: 'Parsing error … Mismatched closing tag'."""
    text = str(exc.__cause__ or exc)
    match = re.search(r"error: \(-?\d+:([^)]*)\) (.*?)(?: in function '(.*)')?\s*$", text, re.S)
    if not match:
        return "unreadable"
    detail = match.group(3) if match.group(3) and ":" in match.group(3) else match.group(2)
    return f"{match.group(1)}: {detail.split(':', 1)[-1].strip()}"[:200]


def _first(node: Any, what: str) -> Any:
    """The first of ``node``'s children named for ``what`` (OPENCV_NODES), or None."""
    for key in OPENCV_NODES[what]:
        child = node.getNode(key)
        if not child.empty() and not child.isNone():
            return child
    return None


def _opencv_view(node: Any, name: str, label: str) -> dict[str, Any]:
    where = f"{label}: camera '{name}'"
    K = _matrix(_node_values(_first(node, "matrix"), where), (3, 3), f"{where} camera matrix")
    dist_node = _first(node, "dist")
    dist = np.zeros(0) if dist_node is None else _vector(_node_values(dist_node, where), where, "distortion")
    rvec_node, R_node, tvec_node = _first(node, "rvec"), _first(node, "R"), _first(node, "tvec")
    if tvec_node is None or (rvec_node is None and R_node is None):
        raise RigError(f"{where}: needs a rotation ({'/'.join(OPENCV_NODES['rvec'] + OPENCV_NODES['R'])}) "
                       f"and a translation ({'/'.join(OPENCV_NODES['tvec'])})")
    rvec = (_matrix(_node_values(rvec_node, where), (3,), f"{where} rvec") if rvec_node is not None
            else _rodrigues(_node_values(R_node, where), where))
    tvec = _matrix(_node_values(tvec_node, where), (3,), f"{where} translation")
    return {"name": name, "projection": {"type": "pinhole", "K": _from_opencv_pixels(K).tolist(),
                                         "dist": dist.tolist(),
                                         "rvec": rvec.tolist(), "tvec": tvec.tolist()}}


def _from_opencv_pixels(K: np.ndarray) -> np.ndarray:
    """K with its principal point moved from OpenCV's pixel centres to ours (+0.5 px)."""
    out = K.copy()
    out[:2, 2] += OPENCV_TO_OURS_PX
    return out


def _node_values(node: Any, where: str) -> np.ndarray:
    """A matrix node (``!!opencv-matrix``) or a sequence of numbers as a flat or 2-D array."""
    if node.isSeq():
        if node.size() > _MAX_NODE_VALUES:
            raise RigError(f"{where}: node '{node.name()}' has {node.size()} values; "
                           f"at most {_MAX_NODE_VALUES}")
        items = [node.at(i) for i in range(node.size())]
        if not all(item.isReal() or item.isInt() for item in items):
            raise RigError(f"{where}: node '{node.name()}' must hold numbers")
        return np.array([item.real() for item in items])
    if node.isMap() and not node.getNode("data").empty():
        rows, cols = node.getNode("rows").real(), node.getNode("cols").real()
        if not (0 < rows * cols <= _MAX_NODE_VALUES):
            raise RigError(f"{where}: node '{node.name()}' is {rows:g}×{cols:g}; "
                           f"at most {_MAX_NODE_VALUES} values")
        try:
            mat = node.mat()
        except (cv2.error, SystemError) as exc:
            raise RigError(f"{where}: node '{node.name()}' is not a matrix ({_cv_reason(exc)})") from None
        if mat is not None:
            arr = np.asarray(mat, dtype=np.float64)
            return arr.ravel() if 1 in arr.shape else arr
    if node.isReal() or node.isInt():
        return np.array([node.real()])
    raise RigError(f"{where}: node '{node.name()}' must be a matrix or a sequence of numbers")


def _rodrigues(values: np.ndarray, where: str) -> np.ndarray:
    """``R`` as a Rodrigues vector: a 3-vector as it is, a 3×3 rotation converted."""
    if values.shape == (3,):
        return _matrix(values, (3,), f"{where} R")
    R = _matrix(values, (3, 3), f"{where} R")
    if not (np.allclose(R @ R.T, np.eye(3), atol=1e-6) and np.linalg.det(R) > 0):
        raise RigError(f"{where}: R is not a rotation matrix (orthonormal, determinant +1)")
    return cv2.Rodrigues(R)[0].ravel()


# ---- DLTdv / Argus -----------------------------------------------------------------------------

N_DLT = 11


def from_dlt(
    source: Source, *, heights: Sequence[float], label: str | None = None,
    videos: Sequence[int] | None = None,
) -> Rig:
    """A rig from DLTdv / Argus DLT coefficients: a ``matrix`` view per camera, ``cam1`` …

    The CSV holds 11 numbers per camera, one column per camera (DLTdv's and Argus's
    ``*_dltCoefs.csv``, 11 rows) or one row per camera (11 columns; an 11×11 file is read
    as columns). With ``L`` the 11 coefficients, DLTdv's image point is
    ``(x, y) = (L1 X + L2 Y + L3 Z + L4, L5 X + L6 Y + L7 Z + L8) / (L9 X + L10 Y + L11 Z + 1)``
    with the origin at the image's bottom left, y up and pixel centres at 1, 2, …; ours is
    ``(u, v) = (x − 0.5, height + 0.5 − y)``, applied to P.

    heights : image height in pixels of each camera, or one for all.
    """
    label = label or _label(source)
    table = _dlt_table(_text(source, label), label)
    cams = table.T if table.shape[0] == N_DLT else table
    if cams.shape[1] != N_DLT:
        raise RigError(f"{label}: DLT coefficients must be 11 rows (one column per camera) or 11 "
                       f"columns (one row per camera), got {table.shape[0]}×{table.shape[1]}")
    if len(cams) > MAX_VIEWS:
        raise RigError(f"{label}: {len(cams)} cameras; at most {MAX_VIEWS} (MAX_VIEWS)")
    h = _heights(heights, len(cams), label)
    views = []
    for i, (coefs, height) in enumerate(zip(cams, h, strict=True)):
        P_dlt = np.append(coefs, 1.0).reshape(3, 4)
        to_ours = np.array([[1.0, 0.0, -0.5], [0.0, -1.0, height + 0.5], [0.0, 0.0, 1.0]])
        P = to_ours @ P_dlt
        views.append({"name": f"cam{i + 1}", "projection": {"type": "matrix", "P": P.tolist()}})
    return _rig(views, videos, label)


def _dlt_table(text: str, label: str) -> np.ndarray:
    """The CSV's numbers as a 2-D array; blank lines skipped."""
    try:
        rows = [r for r in csv.reader(io.StringIO(text)) if any(c.strip() for c in r)]
    except csv.Error as exc:
        raise RigError(f"{label}: not a CSV of DLT coefficients ({exc})") from None
    if not rows:
        raise RigError(f"{label}: no DLT coefficients (an empty file)")
    lengths = sorted({len(r) for r in rows})
    if len(lengths) > 1:
        raise RigError(f"{label}: rows of different lengths ({lengths[0]} and {lengths[-1]} values)")
    try:
        table = np.array([[float(c) for c in r] for r in rows])
    except ValueError as exc:
        raise RigError(f"{label}: DLT coefficients must be numbers ({exc})") from None
    if not np.all(np.isfinite(table)):
        raise RigError(f"{label}: a DLT coefficient is not a finite number")
    return table


def _heights(heights: Sequence[float], n: int, label: str) -> list[float]:
    h = [float(x) for x in heights]
    if len(h) == 1:
        h *= n
    if len(h) != n:
        raise RigError(f"{label}: {n} cameras but {len(h)} image heights; give one per camera or one for all")
    if not all(math.isfinite(x) and 0 < x <= 1e6 for x in h):
        raise RigError(f"image heights must be numbers of pixels > 0, got {heights}")
    return h


# ---- shared -------------------------------------------------------------------------------------


def _label(source: Source) -> str:
    return source.name if isinstance(source, Path) else "calibration file"


def _text(source: Source, label: str) -> str:
    data = read_bounded(source, MAX_RIG_BYTES, label, RigError)
    if isinstance(data, str):
        return data
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise RigError(f"{label}: not UTF-8 text") from None


def _vector(value: Any, where: str, what: str) -> np.ndarray:
    """A distortion vector of 0, 4, 5 or 8 coefficients (OpenCV order)."""
    n = len(value) if isinstance(value, list | tuple | np.ndarray) and np.ndim(value) == 1 else None
    if n not in DIST_LENGTHS:
        raise RigError(f"{where}: {what} must be a list of 0, 4, 5 or 8 coefficients (OpenCV order "
                       f"k1 k2 p1 p2 [k3 [k4 k5 k6]]), got {n if n is not None else repr(value)[:40]}")
    return _matrix(value, (n,), f"{where} {what}")


def _rig(views: list[dict[str, Any]], videos: Sequence[int] | None, label: str) -> Rig:
    """Number the views' videos and validate the rig (its errors prefixed by ``label``)."""
    if videos is not None and len(videos) != len(views):
        raise RigError(f"{label}: {len(views)} cameras but {len(videos)} video indices")
    for i, view in enumerate(views):
        view["video"] = int(videos[i]) if videos is not None else i
    try:
        return Rig.from_dict({"views": views})
    except RigError as exc:
        raise RigError(f"{label}: {exc}") from None

