"""Hostile and broken uploads (issue 5): each gives one clear ValueError subclass, fast.

A service hands user files to the core loaders. Every case below must end in one
:class:`ModelError`, :class:`RigError`, :class:`HistogramError` or :class:`VideoError`
whose message names what is wrong — never a hang, a crash, a NaN, another exception or
an unbounded allocation. Size and time bombs are also timed: ``HANG_GUARD_S`` is only a
guard against a hang on a busy 2-core machine; the figures measured are in each test's
docstring (2-core EPYC, 2026-11-22).
"""

from __future__ import annotations

import copy
import json
import os
import struct
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest

from core import video as video_module
from core import xmlio
from core.histogram import MAX_BINS, HistogramError, Histograms
from core.model import MAX_JOINTS, KinematicModel, ModelError
from core.pipeline import VideoSource
from core.rig import Rig, RigError
from core.video import VideoError, VideoSet, probe

HANG_GUARD_S = 5.0
DATA = Path(__file__).parents[1] / "data"


def _raises_fast(call: Callable[[], object], error: type[ValueError], match: str) -> None:
    """Run ``call``; assert it raises ``error`` matching ``match`` before the hang guard runs out."""
    start = time.perf_counter()
    with pytest.raises(error, match=match):
        call()
    assert time.perf_counter() - start < HANG_GUARD_S


# ---- model XML (FORMATS §1) ----------------------------------------------------------------------

JOINT = '<joint name="a"><dof axis="z" name="q" min="0" max="1"/></joint>'
MARKER = '<marker name="m" joint="a"/>'


def _model(body: str = JOINT + MARKER, head: str = "", attrs: str = 'name="t"') -> str:
    return f"{head}<model {attrs}>{body}</model>"


def _chain(n: int) -> str:
    """A model of ``n`` joints in one chain, each 1 unit along x of its parent, a marker at the tip."""
    free = 'min="-90" max="90"'
    joints = [f'<joint name="j0"><dof axis="z" name="d0" {free}/></joint>'] + [
        f'<joint name="j{i}" parent="j{i - 1}"><offset x="1"/><dof axis="z" name="d{i}" {free}/></joint>'
        for i in range(1, n)
    ]
    return _model("".join(joints) + f'<marker name="tip" joint="j{n - 1}"/>')


XXE = '<!DOCTYPE model [<!ENTITY x SYSTEM "file:///etc/passwd">]>'
LAUGHS = (
    '<!DOCTYPE model [<!ENTITY a "lol">'
    + "".join(f'<!ENTITY {c} "{("&" + p + ";") * 10}">' for p, c in zip("abcdefgh", "bcdefghi", strict=True))
    + "]>"
)
TEN_MB = 10 * 2**20

HOSTILE_MODELS = {
    "external_entity": (lambda: XXE + _model(attrs='name="&x;"'), r"refused unsafe XML \(DTDForbidden\)"),
    "billion_laughs": (lambda: LAUGHS + _model(attrs='name="&i;"'), r"refused unsafe XML \(DTDForbidden\)"),
    "dtd_alone": (lambda: '<!DOCTYPE model SYSTEM "model.dtd">' + _model(),
                  "DTDs and entities are not allowed"),
    "attribute_10_MB": (lambda: _model(attrs=f'name="{"A" * TEN_MB}"'),
                        "<model> attribute 'name' is 10485760 characters long; at most 1024"),
    "number_10_MB": (lambda: _model(JOINT.replace('max="1"', f'max="1{"0" * TEN_MB}"') + MARKER),
                     "<dof> attribute 'max' is 10485761 characters long"),
    "document_over_16_MB": (lambda: _model(JOINT + MARKER + " " * (16 * 2**20)),
                            "model file is larger than 16777216 bytes"),
    "cycle": (lambda: _model(JOINT + '<joint name="b" parent="c"/><joint name="c" parent="b"/>' + MARKER),
              "joints b, c form a cycle"),
    "joints_10000": (lambda: _chain(10_000), "model has 10000 <joint> elements; at most 1000 are allowed"),
    "markers_10000": (lambda: _model(JOINT + '<marker name="m" joint="a"/>' * 10_000),
                      "model has 10000 <marker> elements; at most 1000"),
    "nested_100000_deep": (lambda: _model(JOINT + MARKER + "<x>" * 100_000 + "</x>" * 100_000),
                           "elements are nested more than 16 deep"),
    "elements_200000": (lambda: _model(JOINT + MARKER + "<x/>" * 200_000), "more than 100000 elements"),
    "attributes_1000000_on_one_element": (lambda: _model(attrs=" ".join(f'a{i}="0"' for i in range(10**6))),
                                          r"more than 200000 attributes \(1000007 '=' signs"),
    "not_utf8": (lambda: _model(attrs='name="\xff"').encode("latin-1"),
                 "not well-formed XML: not well-formed"),
    "empty_document": (lambda: "", "not well-formed XML: no element found"),
    "empty_bytes": (lambda: b"", "not well-formed XML: no element found"),
    "wrong_root": (lambda: "<html><body/></html>", "root element is <html>, expected <model>"),
    "nan_offset": (lambda: _model(JOINT.replace("<dof", '<offset x="NaN"/><dof') + MARKER),
                   "joint 'a' <offset>: attribute x='NaN' is not a finite number"),
    "inf_range": (lambda: _model(JOINT.replace('max="1"', 'max="inf"') + MARKER),
                  "joint 'a' dof 'q': attribute max='inf' is not a finite number"),
    "overflowing_number": (lambda: _model(JOINT.replace("<dof", '<offset y="1e400"/><dof') + MARKER),
                           "attribute y='1e400' is not a finite number"),
    "huge_offset": (lambda: _model(JOINT.replace("<dof", '<offset z="1e300"/><dof') + MARKER),
                    r"joint 'a' <offset>: attribute z='1e300' is beyond ±1e\+06"),
    "huge_marker": (lambda: _model(JOINT + '<marker name="m" joint="a" x="-2e6"/>'),
                    r"marker 'm': attribute x='-2e6' is beyond ±1e\+06"),
    "huge_range": (lambda: _model(JOINT.replace('min="0" max="1"', 'min="1e15" max="1e15"') + MARKER),
                   "attribute min='1e15' is beyond"),
}


@pytest.mark.parametrize(("make", "match"), HOSTILE_MODELS.values(), ids=HOSTILE_MODELS.keys())
def test_hostile_model_is_refused_fast(make, match):
    """Measured (building the text included): 10 MB attribute 0.12 s, 10,000 joints 0.21 s,
    200,000 elements 0.22 s (stopped at the 100,001st), a million attributes 0.2 s (counted
    before parsing: parsed, 1.3 million took 4 s and ~350 MB), all others < 0.05 s."""
    source = make()
    _raises_fast(lambda: KinematicModel.from_xml(source), ModelError, match)


@pytest.mark.parametrize(("make", "match"), HOSTILE_MODELS.values(), ids=HOSTILE_MODELS.keys())
def test_hostile_model_file_is_refused_too(tmp_path, make, match):
    """The same bytes from a path (the service stores uploads): the same error."""
    source = make()
    path = tmp_path / "model.xml"
    path.write_bytes(source if isinstance(source, bytes) else source.encode())
    _raises_fast(lambda: KinematicModel.from_xml(path), ModelError, match)


def test_a_huge_model_file_is_not_read_whole(tmp_path):
    """A 1 GB sparse file is refused after reading MAX_XML_BYTES + 1 bytes (measured 0.01 s)."""
    path = tmp_path / "model.xml"
    with path.open("wb") as f:
        f.truncate(2**30)
    _raises_fast(lambda: KinematicModel.from_xml(path), ModelError, "model file is larger than")


@pytest.mark.parametrize("make", [lambda p: p, lambda p: p / "missing.xml"], ids=["directory", "missing"])
def test_a_model_path_that_is_not_a_file_is_refused(tmp_path, make):
    _raises_fast(lambda: KinematicModel.from_xml(make(tmp_path)), ModelError, "cannot read model file")


def test_a_fifo_is_refused_without_blocking(tmp_path):
    """Opening a FIFO for reading blocks until a writer comes: it must not even be opened."""
    fifo = tmp_path / "model.xml"
    os.mkfifo(fifo)
    _raises_fast(lambda: KinematicModel.from_xml(fifo), ModelError, "is not a regular file")


def test_the_joint_limit_is_configurable_and_kinematics_do_not_recurse():
    """10,000 joints in one chain load with ``max_joints`` raised, and forward kinematics put the
    tip at x = 9999 (no recursion, so no RecursionError at Python's limit of 1000).
    Measured: parse 0.4 s, forward kinematics 0.1 s."""
    text = _chain(10_000)
    start = time.perf_counter()
    model = KinematicModel.from_xml(text, max_joints=10_000)
    tip = model.marker_positions(np.zeros(10_000))
    assert time.perf_counter() - start < HANG_GUARD_S
    np.testing.assert_allclose(tip, [[9999.0, 0.0, 0.0]], atol=1e-9)
    assert model.joint_transforms(np.zeros(10_000))[-1, 0, 3] == pytest.approx(9999.0)


def test_a_model_at_the_default_joint_limit_loads():
    model = KinematicModel.from_xml(_chain(MAX_JOINTS))
    assert len(model.joints) == MAX_JOINTS


def test_a_cycle_of_10000_joints_is_found_without_recursion():
    """Every joint's parent is the next one, the last's the first: no root (measured 0.3 s)."""
    n = 10_000
    joints = "".join(f'<joint name="j{i}" parent="j{(i + 1) % n}"/>' for i in range(n))
    text = _model(JOINT + joints + MARKER)
    _raises_fast(lambda: KinematicModel.from_xml(text, max_joints=n + 1), ModelError,
                 "form a cycle")


def test_the_xml_limits_are_module_settings(monkeypatch):
    """A service may lower a limit; it is read when a file is parsed."""
    monkeypatch.setattr(xmlio, "MAX_XML_DEPTH", 2)
    _raises_fast(lambda: KinematicModel.from_xml(_model()), ModelError, "nested more than 2 deep")


def test_numbers_at_the_limit_load_and_give_finite_positions():
    """|value| = MAX_ABS_VALUE everywhere on a 1000-joint chain: positions stay finite."""
    free = 'min="-1000000" max="-999999"'
    big = 'x="1e6" y="-1e6" z="1e6"'
    joints = [f'<joint name="j0"><rest y="1e6"/><dof axis="z" name="d0" {free}/></joint>'] + [
        f'<joint name="j{i}" parent="j{i - 1}"><offset {big}/><dof axis="x" name="d{i}" {free}/></joint>'
        for i in range(1, MAX_JOINTS)
    ]
    model = KinematicModel.from_xml(_model("".join(joints) + f'<marker name="m" joint="j999" {big}/>'))
    assert np.all(np.isfinite(model.marker_positions(model.upper)))



# ---- rig JSON (FORMATS §2) -----------------------------------------------------------------------

AFFINE = {"type": "affine", "matrix": [[3.0, 0, 0, 240], [0, -3.0, 0, 184]]}
UNIT_AFFINE = {"type": "affine", "matrix": [[1, 0, 0, 0], [0, 1, 0, 0]]}
PINHOLE = {"type": "pinhole", "K": [[800.0, 0, 320], [0, 700.0, 240], [0, 0, 1]],
           "dist": [0.01, -0.02, 0.001, 0.002, 0.003], "rvec": [0.1, -0.2, 0.05], "tvec": [0.3, -0.1, 5.0]}


def _view(name: str = "cam", video: int = 0, projection: dict = AFFINE, **extra: object) -> dict:
    return {"name": name, "video": video, "projection": projection, **extra}


def _rig_json(*views: dict) -> str:
    return json.dumps({"views": list(views)})


def _with(projection: dict, **changes: object) -> dict:
    return {**copy.deepcopy(projection), **changes}


def _nested(depth: int) -> list:
    """A list nested ``depth`` deep, built without recursion."""
    outer: list = []
    inner = outer
    for _ in range(depth - 1):
        inner.append([])
        inner = inner[0]
    return outer


HOSTILE_RIG_TEXT = {
    "nan_token": (lambda: _rig_json(_view()).replace("240", "NaN"),
                  "rig contains NaN, which is not a number"),
    "infinity_token": (lambda: _rig_json(_view()).replace("240", "Infinity"), "rig contains Infinity"),
    "minus_infinity_token": (lambda: _rig_json(_view()).replace("184", "-Infinity"),
                             "rig contains -Infinity"),
    "overflowing_number": (lambda: _rig_json(_view()).replace("240", "1e999"),
                           "view 'cam' affine matrix contains a value that is not a finite number"),
    "integer_of_5000_digits": (lambda: _rig_json(_view()).replace('"video": 0', '"video": ' + "9" * 5000),
                               "view 'cam': 'video' must be a non-negative integer index, got inf"),
    "integer_of_400_digits_in_a_matrix": (lambda: _rig_json(_view()).replace("240", "9" * 400),
                                          "affine matrix contains a value that is not a finite number"),
    "deeply_nested_json": (lambda: "[" * 100_000 + "]" * 100_000, "rig JSON is nested too deeply"),
    "deeply_nested_matrix": (lambda: _rig_json(_view(projection={"type": "affine", "matrix": []})).replace(
        "[]", "[" * 100_000 + "]" * 100_000), "rig JSON is nested too deeply"),
    "string_of_10_MB": (lambda: _rig_json(_view(name="x" * TEN_MB)), "rig file is larger than 1048576 bytes"),
    "views_10000": (lambda: _rig_json(*[{"projection": UNIT_AFFINE}] * 10_000),
                    r"rig has 10000 views; at most 256 are allowed \(MAX_VIEWS\)"),
    "top_level_list": (lambda: "[]", "rig must be an object with a list 'views'"),
    "top_level_string": (lambda: '"views"', "rig must be an object with a list 'views'"),
    "top_level_null": (lambda: "null", "rig must be an object with a list 'views'"),
    "empty_document": (lambda: "", "rig is not valid JSON"),
    "not_utf8": (lambda: b'{"views": [{"name": "\xff"}]}', "cannot read rig file"),
}


@pytest.mark.parametrize(("make", "match"), HOSTILE_RIG_TEXT.values(), ids=HOSTILE_RIG_TEXT.keys())
def test_hostile_rig_json_is_refused_fast(make, match):
    """Measured: 10 MB string 0.05 s (refused by size before parsing), 10,000 views (0.7 MB)
    0.09 s (accepted after 1.5 s before), all others < 10 ms."""
    text = make()
    _raises_fast(lambda: Rig.from_json(text), RigError, match)


@pytest.mark.parametrize(("make", "match"), HOSTILE_RIG_TEXT.values(), ids=HOSTILE_RIG_TEXT.keys())
def test_hostile_rig_file_is_refused_too(tmp_path, make, match):
    text = make()
    path = tmp_path / "rig.json"
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    _raises_fast(lambda: Rig.from_json(path), RigError, match)


HOSTILE_RIG_DOCS = {
    "singular_dlt": ({"views": [_view(projection={"type": "matrix",
                                                  "P": [[1, 0, 0, 0], [0, 1, 0, 0], [1, 1, 0, 1]]})]},
                     r"view 'cam': P is singular \(its 3×3 part has rank < 3\)"),
    "rank_deficient_dlt": ({"views": [_view(projection={"type": "matrix",
                                                        "P": [[1, 2, 3, 4], [2, 4, 6, 8], [0, 0, 1, 1]]})]},
                           "view 'cam': P is singular"),
    "all_zero_dlt": ({"views": [_view(projection={"type": "matrix", "P": [[0] * 4] * 3})]},
                     "view 'cam': P is singular"),
    "zero_focal_length": ({"views": [_view(projection=_with(PINHOLE, K=[[0, 0, 3], [0, 7, 2], [0, 0, 1]]))]},
                          r"view 'cam': K must be .* with fx, fy > 0"),
    "nan_distortion": ({"views": [_view(projection=_with(PINHOLE, dist=[float("nan"), 0, 0, 0]))]},
                       "view 'cam' dist contains a value that is not a finite number"),
    "infinite_distortion": ({"views": [_view(projection=_with(PINHOLE, dist=[0, float("inf"), 0, 0, 0]))]},
                            "view 'cam' dist contains a value that is not a finite number"),
    "missing_views": ({"cameras": [_view()]}, "rig must be an object with a list 'views'"),
    "zero_views": ({"views": []}, "rig has no views"),
    "video_index_beyond_the_views": ({"views": [_view(video=3)]},
                                     r"view .cam. uses video 3, but a rig of 1 view\(s\) can use"),
    "video_index_of_a_billion": ({"views": [_view(video=10**9)]}, "view 'cam' uses video 1000000000"),
    "video_index_of_2_to_the_63": ({"views": [_view("a", 0), _view("b", 2**63 - 1)]},
                                   "view 'b' uses video 9223372036854775807"),
    "video_index_skipped": ({"views": [_view("a", 0), _view("b", 2), _view("c", 2)]},
                            r"views use video indices \[0, 2\]: no view uses video 1"),
    "negative_video_index": ({"views": [_view(video=-1)]}, "'video' must be a non-negative integer index"),
    "video_index_of_19_digits": ({"views": [_view(video=10**18)]},
                                 r"uses video 1000000000000000000, but a rig of 1 view\(s\) can use "
                                 r"videos 0\.\.0 at most"),
    "negative_roi": ({"views": [_view(roi=[-1, 0, 10, 10])]}, r"roi must be \[x, y, width, height\]"),
    "roi_beyond_any_frame": ({"views": [_view(roi=[10**9, 0, 10, 10])]},
                             "roi .* reaches beyond the largest frame a video may have"),
    "roi_of_1e300": ({"views": [_view(roi=[0, 0, 1e300, 1e300])]}, "reaches beyond the largest frame"),
    "duplicate_view_names": ({"views": [_view("cam", 0), _view("cam", 0)]}, "duplicate view name 'cam'"),
    "name_of_a_megabyte": ({"views": [_view("x" * 2**20)]}, "view 0: 'name' is 1048576 characters long"),
    "list_nested_100000_deep": ({"views": [_view(projection={"type": "affine", "matrix": _nested(100_000)})]},
                                "view 'cam' affine matrix must be a 2×4 array of numbers"),
    "python_int_beyond_float": ({"views": [_view(projection={"type": "affine",
                                                             "matrix": [[10**400, 0, 0, 0], [0, 1, 0, 0]]})]},
                                "view 'cam' affine matrix must be a 2×4 array of numbers"),
}


@pytest.mark.parametrize(("doc", "match"), HOSTILE_RIG_DOCS.values(), ids=HOSTILE_RIG_DOCS.keys())
def test_hostile_rig_document_is_refused_fast(doc, match):
    """Measured: every case < 1 ms (the 100,000-deep list stops at depth 3)."""
    _raises_fast(lambda: Rig.from_dict(doc), RigError, match)


EXTREME_BUT_FINITE = {
    # 1 + k4 r² = 0 at r² = 1: OpenCV (and this kernel, before) divided by zero there.
    "rational_distortion_pole": _with(PINHOLE, dist=[0, 0, 0, 0, 0, -1, 0, 0], rvec=[0, 0, 0],
                                      tvec=[0, 0, 0]),
    "distortion_of_1e300": _with(PINHOLE, dist=[1e300, 1e300, 0, 0, 1e300]),
    "dlt_of_1e300": {"type": "matrix", "P": [[1e300, 0, 0, 0], [0, 1e300, 0, 0], [0, 0, 1e300, 1]]},
    "affine_of_1e300": {"type": "affine", "matrix": [[1e300, 0, 0, 0], [0, 0, 1e300, 0]]},
}


@pytest.mark.parametrize("projection", EXTREME_BUT_FINITE.values(), ids=EXTREME_BUT_FINITE.keys())
def test_extreme_but_finite_rigs_project_to_finite_pixels(projection):
    """Finite rig numbers can still overflow or hit a pole; every projection must stay finite
    (a NaN or inf would poison Eq. 5 and the Metropolis step), and far ones go far away."""
    rig = Rig.from_dict({"views": [_view(projection=projection)]})
    points = np.array([[0.0, 1.0, 1.0], [1.0, 0.0, 1.0], [1e9, -1e9, 1e9], [0.0, 1e7, 1e-11]])
    got = rig.project(points)
    assert np.all(np.isfinite(got))
    assert np.all(np.abs(got[0, 2]) >= 1e6)


def _two_camera_rig() -> Rig:
    return Rig.from_dict({"views": [_view("side", 0, roi=[0, 0, 360, 288]),
                                    _view("top", 0, roi=[0, 288, 360, 288]),
                                    _view("cam", 1, projection=PINHOLE)]})


@pytest.mark.parametrize(
    ("sizes", "match"),
    [([], r"the rig expects 2 video\(s\), got 0"),
     ([(720, 576)], r"the rig expects 2 video\(s\), got 1"),
     ([(720, 576)] * 3, r"the rig expects 2 video\(s\), got 3"),
     ([(720, 575), (640, 480)],
      r"view 'top': roi \[0, 288, 360, 288\] lies outside the 720×575 frame of video 0"),
     ([(359, 576), (640, 480)], r"view 'side': roi \[0, 0, 360, 288\] lies outside the 359×576 frame"),
     ([(720, 576), (320, 240)],  # a camera calibrated at 640×480 given a half-size video
      r"view 'cam': its principal point \(320, 240\) lies outside the 320×240 frame of video 1: is "
      r"that video this camera's\?")],
    ids=["no_video", "one_video_missing", "one_video_too_many", "roi_below_the_frame",
         "roi_right_of_the_frame", "principal_point_outside_the_frame"],
)
def test_videos_that_do_not_fit_the_rig_are_refused(sizes, match):
    with pytest.raises(RigError, match=match):
        _two_camera_rig().check_videos(sizes)


def test_videos_that_fit_the_rig_pass():
    _two_camera_rig().check_videos([(720, 576), (640, 480)])


def test_to_dict_is_a_deep_copy():
    """Editing the document must not edit the rig (its projections nor its cached arrays)."""
    rig = Rig.from_dict({"views": [_view("a", projection=AFFINE), _view("p", projection=PINHOLE)]})
    before = rig.to_json()
    doc = rig.to_dict()
    doc["views"][0]["projection"]["matrix"][0][0] = 99.0
    doc["views"][1]["projection"]["K"][0][0] = -1.0
    doc["views"][1]["projection"]["type"] = "matrix"
    assert rig.to_json() == before
    assert rig.views[0].projection["matrix"][0][0] == 3.0
    np.testing.assert_array_equal(rig.arrays.P[0, 0], [3.0, 0, 0, 240])


# ---- histogram XML (FORMATS §4) ------------------------------------------------------------------

HINGES = KinematicModel.from_xml(_model(
    '<joint name="a"><dof axis="z" name="p" min="0" max="180"/></joint>'
    '<joint name="b" parent="a"><offset x="1"/><dof axis="z" name="q" min="-90" max="90"/></joint>'
    '<marker name="m" joint="b"/>'
))
P = '<dof name="p" count="10">0.25 0.25 0.5 0</dof>'
Q = '<dof name="q" count="10">1 0 0 0</dof>'


def _hist(dofs: str = P + Q, head: str = "", attrs: str = 'model="t" bins="4"') -> str:
    return f"{head}<histograms {attrs}>{dofs}</histograms>"


HOSTILE_HISTOGRAMS = {
    "external_entity": (lambda: XXE.replace("model", "histograms") + _hist(attrs='model="&x;" bins="4"'),
                        r"refused unsafe XML \(DTDForbidden\)"),
    "billion_laughs": (lambda: LAUGHS.replace("model", "histograms") + _hist(attrs='model="&i;" bins="4"'),
                       r"refused unsafe XML \(DTDForbidden\)"),
    "dtd_alone": (lambda: '<!DOCTYPE histograms SYSTEM "h.dtd">' + _hist(),
                  "DTDs and entities are not allowed"),
    "attribute_10_MB": (lambda: _hist(attrs=f'model="{"A" * TEN_MB}" bins="4"'),
                        "<histograms> attribute 'model' is 10485760 characters long"),
    "document_over_16_MB": (lambda: _hist(P + Q + " " * (16 * 2**20)),
                            "histogram file is larger than 16777216"),
    "nested_100000_deep": (lambda: _hist(P + Q + "<x>" * 100_000 + "</x>" * 100_000),
                           "elements are nested more than 16 deep"),
    "empty_document": (lambda: "", "not well-formed XML: no element found"),
    "wrong_root": (lambda: _hist().replace("histograms", "model"),
                   "root element is <model>, expected <histograms>"),
    "too_few_bins": (lambda: _hist(P.replace("0.5 0", "0.5") + Q), "dof 'p': expected 4 values, got 3"),
    "too_many_bins": (lambda: _hist(P + Q.replace("1 0", "1 0 0 0")), "dof 'q': expected 4 values, got 6"),
    "millions_of_values": (lambda: _hist(P + Q.replace("1 0 0 0", "0 " * 5_000_000)),
                           "dof 'q': expected 4 values, got 5000000"),
    "bins_beyond_the_limit": (lambda: _hist(attrs='model="t" bins="100000000000"'),
                              r"bins=100000000000 is more than 3600 \(MAX_BINS\)"),
    "negative_probability": (lambda: _hist(P.replace("0.25 0.25", "0.75 -0.25") + Q),
                             "dof 'p': values must be non-negative numbers"),
    "nan_probability": (lambda: _hist(P.replace("0.5 0", "0.5 NaN") + Q),
                        "dof 'p': values must be non-negative numbers"),
    "infinite_probability": (lambda: _hist(P.replace("0.5 0", "0.5 inf") + Q),
                             "dof 'p': values must be non-negative numbers"),
    "negative_count": (lambda: _hist(P + Q.replace('count="10"', 'count="-10"')),
                       "dof 'q': count must be a non-negative number"),
    "nan_count": (lambda: _hist(P + Q.replace('count="10"', 'count="nan"')),
                  "dof 'q': count must be a non-negative number"),
    "count_of_1e308": (lambda: _hist(P + Q.replace('count="10"', 'count="1e308"')),
                       r"dof 'q': count 1e\+308 is more than 1e\+300 \(MAX_COUNT\)"),
    "dof_not_in_the_model": (lambda: _hist(P + Q + '<dof name="phi" count="1">1 0 0 0</dof>'),
                             "dof 'phi' is not a rotational DOF of model 't'"),
    "dof_missing": (lambda: _hist(P), r"no histogram for DOF\(s\) q"),
}


@pytest.mark.parametrize(("make", "match"), HOSTILE_HISTOGRAMS.values(), ids=HOSTILE_HISTOGRAMS.keys())
def test_hostile_histograms_are_refused_fast(make, match):
    """Measured: 5,000,000 values 0.9 s with building the text (counted, not converted: 20 MB
    peak under tracemalloc, 218 MB before), 10 MB attribute 0.15 s, the others < 0.05 s."""
    text = make()
    _raises_fast(lambda: Histograms.from_xml(text, HINGES), HistogramError, match)


def test_histograms_with_huge_bins_for_a_model_without_angles_are_refused():
    """No rotational DOF means no <dof> whose values could contradict ``bins``: the limit alone
    keeps the (bins,) tables of s(H) from being allocated."""
    slider = KinematicModel.from_xml(
        _model('<joint name="a"><dof axis="tx" name="t" min="0" max="1"/></joint>' + MARKER)
    )
    _raises_fast(lambda: Histograms.from_xml(_hist("", attrs='model="t" bins="1000000000000"'), slider),
                 HistogramError, "bins=1000000000000 is more than 3600")


def test_histograms_at_the_bin_limit_load():
    uniform = Histograms.uniform(HINGES, bins=MAX_BINS)
    again = Histograms.from_xml(uniform.to_xml(), HINGES)
    np.testing.assert_allclose(again.probs, uniform.probs)


def test_uniform_histograms_beyond_the_bin_limit_are_refused():
    """A bins option from a user (a job setting) is bounded like a file's."""
    _raises_fast(lambda: Histograms.uniform(HINGES, bins=10**9), HistogramError,
                 "bins=1000000000 is more than")


# ---- video ---------------------------------------------------------------------------------------

FRAME_W, FRAME_H = 64, 48


def _avi(path: Path, n: int) -> Path:
    """``n`` tiny MJPG frames, frame i a flat grey 16 + 4 i (so a frame tells its index)."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (FRAME_W, FRAME_H), False)
    for i in range(n):
        writer.write(np.full((FRAME_H, FRAME_W), 16 + 4 * i, dtype=np.uint8))
    writer.release()
    return path


def _announce(path: Path, frames: int) -> Path:
    """Rewrite the frame counts of an AVI's main header (avih) and stream header (strh)."""
    data = bytearray(path.read_bytes())
    avih, strh = data.find(b"avih"), data.find(b"strh")
    struct.pack_into("<I", data, avih + 8 + 16, frames)  # dwTotalFrames
    struct.pack_into("<I", data, strh + 8 + 32, frames)  # dwLength
    path.write_bytes(bytes(data))
    return path


def _write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


def _cut(source: Path, path: Path, keep: float) -> Path:
    """The first ``keep`` (a fraction) of ``source``'s bytes, as ``path``."""
    data = source.read_bytes()
    return _write(path, data[: int(len(data) * keep)])


def _fifo(path: Path) -> Path:
    os.mkfifo(path)
    return path


HOSTILE_VIDEOS = {
    "text_named_avi": (lambda d: _write(d / "trial.avi", b"frame 1: leg up\n" * 100),
                       "not a video file FFmpeg can decode"),
    "random_bytes": (lambda d: _write(d / "trial.avi", np.random.default_rng(5).bytes(50_000)),
                     "not a video file FFmpeg can decode"),
    "h264_cut_in_half": (lambda d: _cut(DATA / "frames_h264.mp4", d / "trial.mp4", 0.5),
                         "not a video file FFmpeg can decode"),
    "avi_cut_inside_its_header": (lambda d: _cut(_avi(d / "full.avi", 10), d / "trial.avi", 0.02),
                                  "not a video file FFmpeg can decode"),
    "zero_bytes": (lambda d: _write(d / "trial.avi", b""), "not a video file FFmpeg can decode"),
    "zero_frames": (lambda d: _avi(d / "trial.avi", 0), "holds no decodable frame"),
    "directory": (lambda d: d, "no such video file"),
    "missing": (lambda d: d / "missing.avi", "no such video file"),
    "fifo": (lambda d: _fifo(d / "trial.avi"), "no such video file"),
    "nul_in_name": (lambda d: str(d / "tri\x00al.avi"), "a video path contains a NUL byte"),
}


@pytest.mark.parametrize(("make", "match"), HOSTILE_VIDEOS.values(), ids=HOSTILE_VIDEOS.keys())
def test_hostile_video_is_refused_fast(tmp_path, make, match):
    """Measured: every case < 20 ms."""
    path = make(tmp_path)
    _raises_fast(lambda: probe(path), VideoError, match)


@pytest.mark.parametrize("announced", [3, 1_000_000, 2**32 - 1], ids=["fewer", "a_million", "uint32_max"])
def test_a_container_that_lies_about_its_frame_count_gives_the_real_one(tmp_path, announced):
    """The AVI headers announce ``announced`` frames; the file holds 10. probe finds 10 by
    decoding, and reading every frame returns frames 0..9 (measured < 5 ms)."""
    path = _announce(_avi(tmp_path / "trial.avi", 10), announced)
    capture = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
    assert capture.get(cv2.CAP_PROP_FRAME_COUNT) == announced  # the lie reaches OpenCV
    capture.release()
    start = time.perf_counter()
    info = probe(path)
    assert time.perf_counter() - start < HANG_GUARD_S
    assert info.frames == 10
    greys = [int(frames[0][0, 0, 0]) for frames in VideoSet([path]).read(0, 10)]
    assert greys == pytest.approx([16 + 4 * i for i in range(10)], abs=2)
    with pytest.raises(ValueError, match=r"frame range \[0, 11\) is not within 0..10"):
        list(VideoSet([path]).read(0, 11))


def _source(videos: list[Path], *views: dict) -> VideoSource:
    return VideoSource(tuple(videos), Rig.from_dict({"views": list(views)}))


def test_a_job_whose_roi_lies_outside_the_video_fails_before_any_frame(tmp_path):
    video = _avi(tmp_path / "trial.avi", 3)
    source = _source([video], _view("side", roi=[0, 0, FRAME_W, FRAME_H + 1]))
    with pytest.raises(RigError, match=r"view 'side': roi \[0, 0, 64, 49\] lies outside the 64×48 frame"):
        len(source)


def test_a_job_with_fewer_videos_than_the_rig_needs_fails_before_any_frame(tmp_path):
    video = _avi(tmp_path / "trial.avi", 3)
    source = _source([video], _view("a", 0), _view("b", 1))
    with pytest.raises(RigError, match=r"the rig expects 2 video\(s\), got 1"):
        len(source)


def test_frames_larger_than_the_limit_are_refused_before_decoding(tmp_path, monkeypatch):
    """The header's frame size is checked, not a decoded frame: lowered to one pixel less
    than the tiny fixture's, the limit refuses it."""
    monkeypatch.setattr(video_module, "MAX_FRAME_PIXELS", FRAME_W * FRAME_H - 1)
    video = _avi(tmp_path / "trial.avi", 1)
    _raises_fast(lambda: probe(video), VideoError, r"frames of 64×48 pixels are larger than 3071 pixels")


def test_frames_at_the_limit_are_read(tmp_path, monkeypatch):
    monkeypatch.setattr(video_module, "MAX_FRAME_PIXELS", FRAME_W * FRAME_H)
    assert probe(_avi(tmp_path / "trial.avi", 1)).frames == 1
