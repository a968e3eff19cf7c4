"""Hostile and broken uploads (issue 5): each gives one clear ValueError subclass, fast.

A service hands user files to the core loaders. Every case below must end in one
:class:`ModelError`, :class:`RigError`, :class:`HistogramError` or :class:`VideoError`
whose message names what is wrong — never a hang, a crash, a NaN, another exception or
an unbounded allocation. Size and time bombs are also timed: ``HANG_GUARD_S`` is only a
guard against a hang on a busy 2-core machine; the figures measured are in each test's
docstring (2-core EPYC, 2026-11-22).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable

import numpy as np
import pytest

from core import model as model_module
from core.model import MAX_JOINTS, KinematicModel, ModelError

HANG_GUARD_S = 5.0


def _raises_fast(call: Callable[[], object], error: type[ValueError], match: str) -> float:
    """Run ``call``, assert it raises ``error`` matching ``match`` within the hang guard; seconds taken."""
    start = time.perf_counter()
    with pytest.raises(error, match=match):
        call()
    elapsed = time.perf_counter() - start
    assert elapsed < HANG_GUARD_S
    return elapsed


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
    """Measured: 10 MB attribute 0.07 s, 10,000 joints 0.4 s, all others < 0.05 s."""
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
    Measured: parse 0.4 s, marker positions 0.01 s."""
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
    monkeypatch.setattr(model_module, "MAX_XML_DEPTH", 2)
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

