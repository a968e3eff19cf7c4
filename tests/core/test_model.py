"""Kinematic model: parsing and validation (FORMATS §1), forward kinematics, the sin/cos kernel."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from core._kernels import sincos_deg
from core.examples import EXAMPLES
from core.model import Dof, Joint, KinematicModel, Marker, ModelError, euler_matrix

LOCUST = EXAMPLES / "locust_hind_leg" / "model.xml"
STICK = EXAMPLES / "stick_insect_front_leg" / "model.xml"


def _xml(body: str, root: str = '<model name="t" units="mm">') -> str:
    """A model document around ``body``; the end tag follows the root's tag."""
    tag = root[1:].split()[0].rstrip(">")
    return f"{root}\n{body}\n</{tag}>\n"


# A valid two-joint model; validation cases change one thing in it.
ROOT = '<joint name="a"><dof axis="z" name="qa" min="-90" max="90"/></joint>'
CHILD = '<joint name="b" parent="a"><offset x="1"/></joint>'
MARKERS = '<marker name="m0" joint="a" x="0" y="0" z="0"/><marker name="m1" joint="b"/>'
VALID = ROOT + CHILD + MARKERS


def _rx(a: float) -> np.ndarray:
    c, s = math.cos(math.radians(a)), math.sin(math.radians(a))
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a: float) -> np.ndarray:
    c, s = math.cos(math.radians(a)), math.sin(math.radians(a))
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a: float) -> np.ndarray:
    c, s = math.cos(math.radians(a)), math.sin(math.radians(a))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


# ---- parsing and writing ------------------------------------------------------------------


def test_parse_locust_example():
    model = KinematicModel.from_xml(LOCUST)
    assert (model.name, model.units) == ("locust_hind_leg", "mm")
    assert [j.name for j in model.joints] == ["body_coxa", "trochanter_femur", "femur_tibia", "tarsus"]
    assert [j.parent for j in model.joints] == [None, "body_coxa", "trochanter_femur", "femur_tibia"]
    assert [j.offset for j in model.joints] == [(0, 0, 0), (4.333, 0, 0), (30.333, 0, 0), (25.667, 0, 0)]
    assert model.dof_names == ["phi", "psi", "alpha", "beta", "gamma"]
    assert [d.axis for d in model.dofs] == ["y", "x", "z", "z", "z"]
    assert model.lower.tolist() == [120, -40, -10, -30, 20]
    assert model.upper.tolist() == [220, 40, 10, 60, 160]
    assert model.rotational.all()
    assert [(m.name, m.joint) for m in model.markers] == [
        ("M0", "body_coxa"), ("M1", "trochanter_femur"), ("M2", "femur_tibia"), ("M3", "tarsus"),
    ]


def test_source_may_be_text_bytes_or_path():
    text = LOCUST.read_text()
    model = KinematicModel.from_xml(LOCUST)
    assert KinematicModel.from_xml(text) == KinematicModel.from_xml(text.encode()) == model


ROUND_TRIP = [
    LOCUST.read_text(),
    STICK.read_text(),
    _xml(  # rest orientations, translational root DOFs, a range crossing 360, awkward numbers and names
        '<joint name="r&amp;&quot;&lt;&gt;">'
        '<offset x="0.1" y="-2.5" z="1e-5"/><rest y="10" x="-20.25" z="90"/>'
        '<dof axis="tx" name="tx" min="-100" max="100"/><dof axis="tz" name="tz" min="0" max="0.001"/>'
        '<dof axis="z" name="wrap" min="300" max="420"/><dof axis="y" name="yaw" min="-180" max="180"/>'
        "</joint>"
        '<joint name="c" parent="r&amp;&quot;&lt;&gt;"><offset x="3"/><rest z="-45"/>'
        '<dof axis="x" name="cx" min="0" max="360"/></joint>'
        '<marker name="M" joint="c" x="1" y="0.333333333333333" z="-7"/>',
        root='<model name="n&amp;m" units="cm">',
    ),
]


@pytest.mark.parametrize("text", ROUND_TRIP, ids=["locust", "stick_insect", "rest_translation_wrap"])
def test_to_xml_round_trip(text):
    model = KinematicModel.from_xml(text)
    again = KinematicModel.from_xml(model.to_xml())
    assert again == model
    assert again.to_xml() == model.to_xml()


def test_round_trip_keeps_range_crossing_360_and_translations():
    model = KinematicModel.from_xml(ROUND_TRIP[2])
    again = KinematicModel.from_xml(model.to_xml())
    assert [(d.name, d.axis, d.min, d.max) for d in again.dofs] == [
        ("tx", "tx", -100, 100), ("tz", "tz", 0, 0.001), ("wrap", "z", 300, 420),
        ("yaw", "y", -180, 180), ("cx", "x", 0, 360),
    ]
    assert again.rotational.tolist() == [False, False, True, True, True]
    assert again.joints[0].rest == {"y": 10, "x": -20.25, "z": 90}
    assert again.joints[0].name == 'r&"<>' and again.name == "n&m"


def test_round_trip_keeps_whitespace_in_names():
    """Tab, LF and CR in a name (from character references) must not become spaces."""
    model = KinematicModel.from_xml(_xml(
        '<joint name="r&#10;1"><dof axis="z" name="q&#9;1" min="0" max="1"/></joint>'
        '<marker name="m&#13;" joint="r&#10;1"/>'
    ))
    assert (model.joints[0].name, model.dof_names, model.markers[0].name) == ("r\n1", ["q\t1"], "m\r")
    assert KinematicModel.from_xml(model.to_xml()) == model


def test_to_xml_writes_no_exponent():
    model = KinematicModel.from_xml(ROUND_TRIP[2])
    assert 'z="0.00001"' in model.to_xml()


# ---- validation: one case per branch, each naming the offending element ---------------------

BILLION_LAUGHS = (
    '<?xml version="1.0"?>\n<!DOCTYPE model [\n <!ENTITY a "lol">\n'
    ' <!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;">\n <!ENTITY c "&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;">\n'
    ' <!ENTITY d "&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;">\n]>\n'
    '<model name="&d;"><joint name="a"><dof axis="z" name="q" min="0" max="1"/></joint>'
    '<marker name="m" joint="a"/></model>'
)
XXE = (
    '<?xml version="1.0"?>\n<!DOCTYPE model [<!ENTITY xxe SYSTEM "file:///etc/passwd">]>\n'
    '<model name="&xxe;"><joint name="a"><dof axis="z" name="q" min="0" max="1"/></joint>'
    '<marker name="m" joint="a"/></model>'
)
DTD_ONLY = '<!DOCTYPE model SYSTEM "http://example.com/model.dtd">\n' + _xml(VALID)

INVALID = {
    "unknown_parent": (_xml(ROOT + CHILD.replace('parent="a"', 'parent="nope"') + MARKERS),
                       "joint 'b': parent 'nope' is not a joint"),
    "cycle": (_xml(ROOT + '<joint name="b" parent="c"/><joint name="c" parent="b"/>' + MARKERS),
              "joints b, c form a cycle"),
    "self_parent": (_xml(ROOT + '<joint name="b" parent="b"/>' + MARKERS), "joints b form a cycle"),
    "no_root": (_xml(ROOT.replace('name="a"', 'name="a" parent="b"') + CHILD + MARKERS),
                "no root joint"),
    "two_roots": (_xml(ROOT + CHILD.replace(' parent="a"', "") + MARKERS),
                  r"2 root joints \(a, b\)"),
    "no_joint": (_xml(""), "no <joint>"),
    "duplicate_joint": (_xml(ROOT + CHILD + CHILD + MARKERS), "duplicate joint name 'b'"),
    "duplicate_dof": (_xml(ROOT + '<joint name="b" parent="a"><dof axis="x" name="qa" min="0" max="1"/>'
                              "</joint>" + MARKERS), "duplicate dof name 'qa'"),
    "duplicate_marker": (_xml(ROOT + CHILD + MARKERS + '<marker name="m1" joint="a"/>'),
                         "duplicate marker name 'm1'"),
    "min_equals_max": (_xml(VALID.replace('min="-90" max="90"', 'min="10" max="10"')),
                       "joint 'a' dof 'qa': min=10 must be smaller than max=10"),
    "min_above_max": (_xml(VALID.replace('min="-90" max="90"', 'min="11" max="10"')),
                      "joint 'a' dof 'qa': min=11 must be smaller than max=10"),
    "unknown_axis": (_xml(VALID.replace('axis="z"', 'axis="w"')),
                     "joint 'a' dof 'qa': unknown axis 'w'"),
    "missing_axis": (_xml(VALID.replace('axis="z" ', "")), "joint 'a' dof 'qa': unknown axis ''"),
    "marker_unknown_joint": (_xml(ROOT + CHILD + '<marker name="m0" joint="nope"/>'),
                             "marker 'm0': joint 'nope' is not a joint"),
    "not_a_number": (_xml(ROOT + CHILD + '<marker name="m0" joint="a" x="abc"/>'),
                     "marker 'm0': attribute x='abc' is not a number"),
    "digit_separator": (_xml(ROOT + CHILD.replace('x="1"', 'x="4_333"') + MARKERS),
                        "joint 'b' <offset>: attribute x='4_333' is not a number"),
    "non_ascii_digits": (_xml(ROOT + CHILD.replace('x="1"', 'x="\u0661"') + MARKERS),
                         "joint 'b' <offset>: attribute x='\u0661' is not a number"),
    "nan": (_xml(VALID.replace('max="90"', 'max="nan"')),
            "joint 'a' dof 'qa': attribute max='nan' is not a finite number"),
    "inf": (_xml(ROOT + '<joint name="b" parent="a"><rest z="inf"/></joint>' + MARKERS),
            "joint 'b' <rest>: attribute z='inf' is not a finite number"),
    "minus_infinity": (_xml(VALID.replace('min="-90"', 'min="-Infinity"')),
                       "joint 'a' dof 'qa': attribute min='-Infinity' is not a finite number"),
    "missing_min": (_xml(VALID.replace('min="-90" ', "")), "joint 'a' dof 'qa': missing attribute 'min'"),
    "translation_not_on_root": (
        _xml(ROOT + '<joint name="b" parent="a"><dof axis="tx" name="t" min="0" max="1"/></joint>' + MARKERS),
        "joint 'b' dof 't': translational axis 'tx' is only allowed on the root",
    ),
    "two_dofs_one_axis": (
        _xml(VALID.replace("</joint>", '<dof axis="z" name="q2" min="0" max="1"/></joint>', 1)),
        "joint 'a': two dofs on axis 'z'",
    ),
    "range_over_360": (_xml(VALID.replace('min="-90" max="90"', 'min="0" max="360.5"')),
                       r"joint 'a' dof 'qa': range 0..360.5 spans more than 360"),
    "no_markers": (_xml(ROOT + CHILD), "no <marker>"),
    "no_dofs": (_xml('<joint name="a"/>' + CHILD + MARKERS), "no <dof>"),
    "joint_without_name": (_xml('<joint><dof axis="z" name="q" min="0" max="1"/></joint>' + MARKERS),
                           "<joint> without a name"),
    "dof_without_name": (_xml(VALID.replace('name="qa" ', "")), "joint 'a': <dof> without a name"),
    "marker_without_name": (_xml(ROOT + CHILD + '<marker joint="a"/>'), "<marker> without a name"),
    "marker_without_joint": (_xml(ROOT + CHILD + '<marker name="m0"/>'),
                             "marker 'm0': missing attribute 'joint'"),
    "unknown_element": (_xml(VALID + "<segment/>"), "<model> contains unknown element <segment>"),
    "wrong_root": (_xml(VALID, root="<modle>"), "root element is <modle>, expected <model>"),
    "malformed": (_xml(VALID).replace("</model>", ""), "not well-formed XML"),
    "external_entity": (XXE, "refused unsafe XML"),
    "dtd": (DTD_ONLY, "refused unsafe XML"),
    "billion_laughs": (BILLION_LAUGHS, "refused unsafe XML"),
}


def test_the_validation_cases_start_from_a_valid_model():
    model = KinematicModel.from_xml(_xml(VALID))
    assert model.dof_names == ["qa"] and [m.name for m in model.markers] == ["m0", "m1"]


@pytest.mark.parametrize(("text", "match"), INVALID.values(), ids=INVALID.keys())
def test_invalid_model(text, match):
    with pytest.raises(ModelError, match=match):
        KinematicModel.from_xml(text)


def test_unreadable_file(tmp_path):
    with pytest.raises(ModelError, match="cannot read model file"):
        KinematicModel.from_xml(tmp_path / "missing.xml")


CODE_JOINTS = (Joint("a", None), Joint("b", "a", (1.0, 0.0, 0.0)))
CODE_MARKERS = (Marker("m", "b", (0.0, 0.0, 0.0)),)


def test_constructor_validates_too():
    with pytest.raises(ModelError, match="duplicate joint name 'a'"):
        KinematicModel("m", "mm", (*CODE_JOINTS, Joint("a", None)), (Dof("q", "a", "z", 0, 1),), CODE_MARKERS)


def test_constructor_dof_on_unknown_joint():
    with pytest.raises(ModelError, match="dof 'q': joint 'ghost' is not a joint"):
        KinematicModel("m", "mm", CODE_JOINTS, (Dof("q", "ghost", "z", 0, 1),), CODE_MARKERS)


def test_constructor_dofs_out_of_joint_order():
    """model.xml nests dofs in joints: another order could not survive to_xml/from_xml."""
    dofs = (Dof("qb", "b", "z", 0, 1), Dof("qa", "a", "z", 0, 1))
    with pytest.raises(ModelError, match="dof 'qa': dofs must be listed joint by joint"):
        KinematicModel("m", "mm", CODE_JOINTS, dofs, CODE_MARKERS)
    model = KinematicModel("m", "mm", CODE_JOINTS, dofs[::-1], CODE_MARKERS)
    assert KinematicModel.from_xml(model.to_xml()) == model


# ---- forward kinematics by hand ---------------------------------------------------------------


def _planar_chain(L1: float, L2: float, L3: float) -> KinematicModel:
    free = 'min="-180" max="180"'
    return KinematicModel.from_xml(_xml(
        f'<joint name="j0"><dof axis="z" name="a" {free}/></joint>'
        f'<joint name="j1" parent="j0"><offset x="{L1}"/><dof axis="z" name="b" {free}/></joint>'
        f'<joint name="j2" parent="j1"><offset x="{L2}"/><dof axis="z" name="c" {free}/></joint>'
        f'<joint name="j3" parent="j2"><offset x="{L3}"/></joint>'
        '<marker name="m0" joint="j0"/><marker name="m1" joint="j1"/>'
        '<marker name="m2" joint="j2"/><marker name="m3" joint="j3"/>'
    ))


@pytest.mark.parametrize(
    ("a", "b", "c"), [(0, 0, 0), (90, 0, 0), (30, 45, -60), (-120, 170, 35), (180, -90, 90)]
)
def test_planar_chain_closed_form(a, b, c):
    L1, L2, L3 = 2.0, 3.0, 1.5
    got = _planar_chain(L1, L2, L3).marker_positions(np.array([a, b, c], dtype=float))
    ra, rab, rabc = math.radians(a), math.radians(a + b), math.radians(a + b + c)
    expected = [
        (0, 0, 0),
        (L1 * math.cos(ra), L1 * math.sin(ra), 0),
        (L1 * math.cos(ra) + L2 * math.cos(rab), L1 * math.sin(ra) + L2 * math.sin(rab), 0),
        (
            L1 * math.cos(ra) + L2 * math.cos(rab) + L3 * math.cos(rabc),
            L1 * math.sin(ra) + L2 * math.sin(rab) + L3 * math.sin(rabc),
            0,
        ),
    ]
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)


def test_rest_orientation_turns_the_child_offset():
    """rest z=90 on b turns b's frame: c's offset (1, 0, 0) goes along world +y; b's own offset does not."""
    model = KinematicModel.from_xml(_xml(
        '<joint name="a"><dof axis="z" name="qa" min="-180" max="180"/></joint>'
        '<joint name="b" parent="a"><offset x="1"/><rest z="90"/></joint>'
        '<joint name="c" parent="b"><offset x="1"/></joint>'
        '<marker name="mb" joint="b" x="0" y="0" z="2"/><marker name="mc" joint="c" x="0.5"/>'
    ))
    at = model.marker_positions
    np.testing.assert_allclose(at(np.array([0.0])), [(1, 0, 2), (1, 1.5, 0)], atol=1e-15)
    # qa = 90 turns everything below a once more: b at (0, 1), c at (-1, 1), mc along -x.
    np.testing.assert_allclose(at(np.array([90.0])), [(0, 1, 2), (-1.5, 1, 0)], atol=1e-15)


def test_root_rest_orientation_and_dofs_compose():
    """W = R(rest) · R(dofs) for the root: a marker sees rest first, then the dof rotation."""
    model = KinematicModel.from_xml(_xml(
        '<joint name="a"><rest x="90"/><dof axis="z" name="qa" min="-180" max="180"/></joint>'
        '<marker name="m" joint="a" x="1"/>'
    ))
    for qa in (0.0, 30.0, -75.0):
        expected = _rx(90) @ _rz(qa) @ [1, 0, 0]
        np.testing.assert_allclose(model.marker_positions(np.array([qa]))[0], expected, atol=1e-15)


EULER = _xml(
    '<joint name="j"><offset x="1" y="-2" z="0.5"/>'
    '<dof axis="z" name="qz" min="-180" max="180"/><dof axis="y" name="qy" min="-180" max="180"/>'
    '<dof axis="x" name="qx" min="-180" max="180"/></joint>'
    '<marker name="m" joint="j" x="1" y="2" z="3"/>'
)


@pytest.mark.parametrize(
    ("z", "y", "x"), [(0, 0, 0), (90, 0, 0), (0, 90, 0), (0, 0, 90), (30, -50, 70), (-170, 20, 135)]
)
def test_euler_convention_y_x_z_whatever_the_dof_order(z, y, x):
    model = KinematicModel.from_xml(EULER)  # dofs listed z, y, x; composition stays Ry·Rx·Rz
    R = _ry(y) @ _rx(x) @ _rz(z)
    q = np.array([z, y, x], dtype=float)
    np.testing.assert_allclose(model.marker_positions(q)[0], [1, -2, 0.5] + R @ [1, 2, 3], atol=1e-13)
    W = model.joint_transforms(q)[0]
    np.testing.assert_allclose(W[:3, :3], R, atol=1e-15)
    np.testing.assert_allclose(W[:3, 3], [1, -2, 0.5], atol=0)
    np.testing.assert_allclose(W[3], [0, 0, 0, 1], atol=0)
    np.testing.assert_allclose(euler_matrix(y, x, z), R, atol=1e-15)


def test_euler_by_hand_90_degrees():
    """Rz(90) sends x to y, Rx(90) sends y to z, Ry(90) sends z to x (active, right-handed)."""
    np.testing.assert_allclose(euler_matrix(0, 0, 90) @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(euler_matrix(0, 90, 0) @ [0, 1, 0], [0, 0, 1], atol=1e-15)
    np.testing.assert_allclose(euler_matrix(90, 0, 0) @ [0, 0, 1], [1, 0, 0], atol=1e-15)
    # Ry·Rx·Rz on x: Rz -> y, Rx -> z, Ry -> x.
    np.testing.assert_allclose(euler_matrix(90, 90, 90) @ [1, 0, 0], [1, 0, 0], atol=1e-15)


def test_translational_root():
    model = KinematicModel.from_xml(_xml(
        '<joint name="r"><offset x="1" y="2" z="3"/>'
        '<dof axis="tz" name="tz" min="-50" max="50"/><dof axis="tx" name="tx" min="-50" max="50"/>'
        '<dof axis="ty" name="ty" min="-50" max="50"/><dof axis="z" name="qz" min="-180" max="180"/></joint>'
        '<joint name="c" parent="r"><offset x="2"/></joint>'
        '<marker name="m0" joint="r"/><marker name="m1" joint="c" y="1"/>'
    ))
    assert model.rotational.tolist() == [False, False, False, True]
    q = np.array([30.0, 10.0, 20.0, 90.0])  # tz, tx, ty, qz
    root = np.array([1 + 10, 2 + 20, 3 + 30])
    # The child's offset (2, 0, 0) and the marker (0, 1, 0) turn with qz = 90.
    child_marker = root + np.array([0, 2, 0]) + np.array([-1, 0, 0])
    np.testing.assert_allclose(model.marker_positions(q), [root, child_marker], atol=1e-14)
    W = model.joint_transforms(q)
    np.testing.assert_allclose(W[0, :3, 3], root, atol=0)
    np.testing.assert_allclose(W[1, :3, :3], _rz(90), atol=1e-15)


def test_joint_transforms_in_file_order_even_when_children_come_first():
    model = KinematicModel.from_xml(_xml(
        '<joint name="tip" parent="mid"><offset x="1"/></joint>'
        '<joint name="mid" parent="base"><offset x="2"/><dof axis="z" name="b" min="-180" max="180"/></joint>'
        '<joint name="base"><offset z="5"/><dof axis="z" name="a" min="-180" max="180"/></joint>'
        '<marker name="m_tip" joint="tip"/><marker name="m_mid" joint="mid"/>'
        '<marker name="m_base" joint="base"/>'
    ))
    a, b = 90.0, -90.0
    W = model.joint_transforms(np.array([b, a]))  # dofs in file order: b (mid) then a (base)
    np.testing.assert_allclose(W[:, :3, 3], [(1, 2, 5), (0, 2, 5), (0, 0, 5)], atol=1e-15)
    np.testing.assert_allclose(W[0, :3, :3], np.eye(3), atol=1e-15)  # a + b = 0
    np.testing.assert_allclose(W[1, :3, :3], _rz(a + b), atol=1e-15)
    np.testing.assert_allclose(W[2, :3, :3], _rz(a), atol=1e-15)
    np.testing.assert_allclose(model.marker_positions(np.array([b, a])), W[:, :3, 3], atol=0)


def test_joint_transforms_locust_origins_match_markers():
    model = KinematicModel.from_xml(LOCUST)  # markers at the joint origins
    q = np.array([170.0, 12.0, -5.0, 30.0, 100.0])
    W = model.joint_transforms(q)
    np.testing.assert_allclose(W[:, :3, 3], model.marker_positions(q), atol=1e-13)
    np.testing.assert_allclose(W[:, 3], np.tile([0, 0, 0, 1.0], (4, 1)), atol=0)
    R0 = _ry(170) @ _rx(12) @ _rz(-5)
    np.testing.assert_allclose(W[0, :3, :3], R0, atol=1e-15)
    np.testing.assert_allclose(W[1, :3, :3], R0 @ _rz(30), atol=1e-15)
    np.testing.assert_allclose(W[3, :3, 3], W[2, :3, 3] + W[2, :3, :3] @ [25.667, 0, 0], atol=1e-13)


def test_vectorised_equals_per_posture():
    model = KinematicModel.from_xml(STICK)
    rng = np.random.default_rng(3)
    q = rng.uniform(model.lower, model.upper, (7, len(model.dofs)))
    many = model.marker_positions(q)
    assert many.shape == (7, len(model.markers), 3)
    for t in range(7):
        np.testing.assert_array_equal(many[t], model.marker_positions(q[t]))
    assert model.marker_positions(q[:0]).shape == (0, len(model.markers), 3)


@pytest.mark.parametrize("shape", [(4,), (6,), (2, 4), (2, 2, 5), ()])
def test_marker_positions_wrong_shape(shape):
    model = KinematicModel.from_xml(LOCUST)  # D = 5
    with pytest.raises(ValueError, match=r"dofs must have shape \(D,\) or \(T, D\) with D=5"):
        model.marker_positions(np.zeros(shape))


def test_marker_positions_scalar_for_one_dof_model():
    model = KinematicModel.from_xml(_xml(VALID))  # D = 1: a scalar is still not a (D,) posture
    with pytest.raises(ValueError, match=r"dofs must have shape \(D,\) or \(T, D\) with D=1"):
        model.marker_positions(np.float64(3.0))


@pytest.mark.parametrize("shape", [(2, 5), (1, 5), (4,), ()])
def test_joint_transforms_wrong_shape(shape):
    model = KinematicModel.from_xml(LOCUST)
    with pytest.raises(ValueError, match=r"dofs must have shape \(D,\)"):
        model.joint_transforms(np.zeros(shape))


# ---- properties ----------------------------------------------------------------------------------


@st.composite
def models(draw) -> KinematicModel:
    """Small random trees: parents drawn among earlier joints, joints then shuffled in the file."""
    n = draw(st.integers(1, 5))
    coord = st.floats(-10, 10, allow_nan=False).map(lambda v: round(v, 3))
    angle = st.floats(-360, 360, allow_nan=False).map(lambda v: round(v, 2))
    parents = [None] + [draw(st.integers(0, i - 1)) for i in range(1, n)]
    joints, dofs = [], []
    for i, p in enumerate(parents):
        offset = (draw(coord), draw(coord), draw(coord))
        rest = {a: draw(angle) for a in "yxz"}
        joints.append(Joint(f"j{i}", None if p is None else f"j{p}", offset, rest))
        for axis in draw(st.sets(st.sampled_from(["x", "y", "z"]))):
            lo = draw(st.integers(-3600, 3600)) / 10
            hi = lo + draw(st.integers(5, 3600)) / 10  # may be 360.0000000001 wide: skip those
            if hi - lo <= 360:
                dofs.append(Dof(f"q{i}{axis}", f"j{i}", axis, lo, hi))
    if not dofs:
        dofs.append(Dof("q0z", "j0", "z", -90.0, 90.0))
    for axis in draw(st.sets(st.sampled_from(["tx", "ty", "tz"]))):
        dofs.append(Dof(f"t{axis}", "j0", axis, -5.0, 5.0))
    markers = [
        Marker(f"m{k}", f"j{draw(st.integers(0, n - 1))}", (draw(coord), draw(coord), draw(coord)))
        for k in range(draw(st.integers(1, 6)))
    ]
    order = draw(st.permutations(range(n)))
    rank = {f"j{i}": k for k, i in enumerate(order)}
    dofs.sort(key=lambda d: rank[d.joint])  # model.xml lists dofs joint by joint
    return KinematicModel("random", "mm", tuple(joints[i] for i in order), tuple(dofs), tuple(markers))


@st.composite
def model_and_posture(draw):
    model = draw(st.one_of(
        st.sampled_from([KinematicModel.from_xml(LOCUST), KinematicModel.from_xml(STICK)]), models()
    ))
    u = np.array([draw(st.floats(0, 1)) for _ in model.dofs])
    return model, model.lower + u * (model.upper - model.lower)


@settings(max_examples=150, deadline=None)
@given(model_and_posture())
def test_rigid_segments_and_orthonormal_rotations(case):
    model, q = case
    W = model.joint_transforms(q)
    index = {j.name: i for i, j in enumerate(model.joints)}
    R, origin = W[:, :3, :3], W[:, :3, 3]
    # Rotations: orthonormal, det +1.
    np.testing.assert_allclose(R @ R.transpose(0, 2, 1), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    # Segment lengths: |origin(child) - origin(parent)| = |offset(child)|.
    for i, j in enumerate(model.joints):
        if j.parent is not None:
            seg = np.linalg.norm(origin[i] - origin[index[j.parent]])
            assert seg == pytest.approx(np.linalg.norm(j.offset), abs=1e-10)
    # Markers: W_joint · p, so distances between markers of one joint are those in its frame.
    world = model.marker_positions(q)
    for k, m in enumerate(model.markers):
        np.testing.assert_allclose(world[k], (W[index[m.joint]] @ [*m.position, 1.0])[:3], atol=1e-10)
        for k2, m2 in enumerate(model.markers[:k]):
            if m2.joint == m.joint:
                d_local = np.linalg.norm(np.subtract(m.position, m2.position))
                assert np.linalg.norm(world[k] - world[k2]) == pytest.approx(d_local, abs=1e-10)


@settings(max_examples=60, deadline=None)
@given(models())
def test_random_models_round_trip(model):
    assert KinematicModel.from_xml(model.to_xml()) == model


@settings(max_examples=500, deadline=None)
@given(st.floats(-1000, 1000, allow_nan=False, allow_infinity=False))
def test_sincos_deg_matches_libm(angle):
    s, c = sincos_deg(angle)
    assert abs(s - math.sin(math.radians(angle))) <= 1e-14
    assert abs(c - math.cos(math.radians(angle))) <= 1e-14


@pytest.mark.parametrize(
    "angle", [0.0, 45.0, 90.0, 180.0, 270.0, -90.0, 360.0, -45.0, 135.0, 1000.0, -1000.0]
)
def test_sincos_deg_quadrants(angle):
    s, c = sincos_deg(angle)
    assert s == pytest.approx(math.sin(math.radians(angle)), abs=1e-15)
    assert c == pytest.approx(math.cos(math.radians(angle)), abs=1e-15)
