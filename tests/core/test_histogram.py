"""Joint-angle histograms: uniform prior, Eq. 4, merge, circular statistics, FORMATS §4."""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from core.histogram import HistogramError, Histograms
from core.model import KinematicModel

# Three rotational DOFs (plain, crossing 0, crossing 360) and a translation without histogram.
MODEL = KinematicModel.from_xml(
    '<model name="h" units="mm">'
    '<joint name="r"><dof axis="tx" name="tx" min="-5" max="5"/>'
    '<dof axis="y" name="a" min="120" max="220"/><dof axis="z" name="b" min="-10" max="10"/></joint>'
    '<joint name="c" parent="r"><offset x="1"/><dof axis="z" name="w" min="300" max="420"/></joint>'
    '<marker name="m" joint="c"/></model>'
)
# One DOF over 0..180: with 4 bins (centres 45, 135, 225, 315) the prior covers bins 0 and 1.
HINGE = KinematicModel.from_xml(
    '<model name="hinge"><joint name="r"><dof axis="z" name="q" min="0" max="180"/></joint>'
    '<marker name="m" joint="r"/></model>'
)


def _bins(*ranges: tuple[int, int]) -> list[int]:
    return sorted(i for lo, hi in ranges for i in range(lo, hi))


# ---- uniform prior -----------------------------------------------------------------------------


def test_uniform_names_exclude_translations():
    h = Histograms.uniform(MODEL, prior_weight=7)
    assert h.names == ("a", "b", "w") and h.model == "h" and h.bins == 360
    assert h.lower.tolist() == [120, -10, 300] and h.upper.tolist() == [220, 10, 420]
    assert h.counts.tolist() == [7, 7, 7]


@pytest.mark.parametrize(
    ("row", "expected"),
    [(0, _bins((120, 220))), (1, _bins((350, 360), (0, 10))), (2, _bins((300, 360), (0, 60)))],
    ids=["120..220", "-10..10", "300..420"],
)
def test_uniform_mass_exactly_on_the_range(row, expected):
    p = Histograms.uniform(MODEL).probs[row]
    assert np.flatnonzero(p).tolist() == expected
    np.testing.assert_array_equal(p[expected], 1.0 / len(expected))
    assert p.sum() == pytest.approx(1.0, abs=1e-12)


def test_uniform_coarse_bins_and_narrow_range():
    h = Histograms.uniform(HINGE, bins=4, prior_weight=2)
    assert h.probs.tolist() == [[0.5, 0.5, 0.0, 0.0]]
    narrow = KinematicModel.from_xml(
        '<model><joint name="r"><dof axis="z" name="q" min="10.2" max="10.4"/></joint>'
        '<marker name="m" joint="r"/></model>'
    )
    # No bin centre inside the range: the bin of the midpoint.
    assert np.flatnonzero(Histograms.uniform(narrow).probs[0]).tolist() == [10]


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"bins": 0}, "bins must be at least 1"),
        ({"prior_weight": 0}, "prior_weight must be a positive finite number"),
        ({"prior_weight": -1}, "prior_weight must be a positive finite number"),
        ({"prior_weight": math.nan}, "prior_weight must be a positive finite number"),
        ({"prior_weight": math.inf}, "prior_weight must be a positive finite number"),
        ({"prior_weight": 1e308}, r"at most 1e\+300 \(MAX_COUNT\)"),  # two such priors merged: inf
    ],
)
def test_uniform_validation(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Histograms.uniform(MODEL, **kwargs)


def test_empty():
    h = Histograms.empty(MODEL, bins=8)
    assert h.probs.shape == (3, 8) and not h.probs.any() and not h.counts.any()


# ---- Eq. 4 ----------------------------------------------------------------------------------------


def test_eq4_by_hand():
    """H_N = ((N-1)·H_{N-1} + Δ)/N from H_2 = [1/2, 1/2, 0, 0]."""
    h = Histograms.uniform(HINGE, bins=4, prior_weight=2)
    h.update(np.array([200.0]))  # bin 2: H_3 = (2·[1/2, 1/2, 0, 0] + [0, 0, 1, 0]) / 3
    np.testing.assert_allclose(h.probs, [[1 / 3, 1 / 3, 1 / 3, 0]], rtol=1e-15)
    assert h.counts.tolist() == [3]
    h.update(np.array([-350.0]))  # = 10 degrees, bin 0: H_4 = (3·H_3 + [1, 0, 0, 0]) / 4
    np.testing.assert_allclose(h.probs, [[1 / 2, 1 / 4, 1 / 4, 0]], rtol=1e-15)
    assert h.counts.tolist() == [4]


def test_eq4_from_empty_is_the_frequency():
    h = Histograms.empty(HINGE, bins=4)
    for angle in (10.0, 100.0, 20.0, 300.0):
        h.update(np.array([angle]))
    np.testing.assert_allclose(h.probs, [[0.5, 0.25, 0.0, 0.25]], rtol=1e-15)
    assert h.counts.tolist() == [4]


@pytest.mark.parametrize(
    ("angle", "bin_"),
    [(0.0, 0), (89.999, 0), (90.0, 1), (359.9, 3), (360.0, 0), (720.5, 0), (-1.0, 3), (-90.0, 3),
     (-90.0001, 2), (-1e-20, 3), (1e-300, 0)],
)
def test_bin_index_wraps_into_0_360(angle, bin_):
    assert Histograms.empty(HINGE, bins=4).bin_index(np.array([angle])).tolist() == [bin_]


@pytest.mark.parametrize("shape", [(2,), (1, 3), ()])
def test_update_wrong_shape(shape):
    with pytest.raises(ValueError, match=r"angles must have shape \(3,\)"):
        Histograms.uniform(MODEL).update(np.zeros(shape))


# ---- merge ------------------------------------------------------------------------------------------


def _observed(angles: np.ndarray, bins: int) -> Histograms:
    h = Histograms.empty(MODEL, bins=bins)
    for a in angles:
        h.update(a)
    return h


def _assert_same(h1: Histograms, h2: Histograms) -> None:
    np.testing.assert_allclose(h1.probs, h2.probs, rtol=0, atol=1e-12)
    np.testing.assert_allclose(h1.counts, h2.counts, rtol=1e-12, atol=0)
    assert h1.names == h2.names


@settings(max_examples=40, deadline=None)
@given(st.integers(2, 60), st.data(), st.sampled_from([4, 36, 360]), st.floats(0.5, 500))
def test_merge_equals_sequential_update(n, data, bins, prior_weight):
    seed = data.draw(st.integers(0, 2**32 - 1))
    split = data.draw(st.integers(1, n - 1))
    angles = np.random.default_rng(seed).uniform(-720, 720, (n, 3))
    prior = Histograms.uniform(MODEL, prior_weight=prior_weight, bins=bins)
    sequential = prior.copy()
    for a in angles:
        sequential.update(a)
    first, second = _observed(angles[:split], bins), _observed(angles[split:], bins)
    _assert_same(prior.merge(first, second), sequential)
    _assert_same(prior.merge(first).merge(second), sequential)
    _assert_same(prior.merge(second, first), sequential)
    head = prior.copy()
    for a in angles[:split]:
        head.update(a)
    _assert_same(head.merge(second), sequential)
    np.testing.assert_allclose(sequential.counts, prior_weight + n, rtol=1e-12)  # n times += 1.0


def test_merge_leaves_inputs_alone():
    prior, obs = Histograms.uniform(MODEL), _observed(np.full((3, 3), 100.0), 360)
    p0, o0 = prior.copy(), obs.copy()
    prior.merge(obs)
    _assert_same(prior, p0)
    _assert_same(obs, o0)


def test_merge_with_empty_is_identity():
    h = Histograms.uniform(MODEL, prior_weight=3)
    h.update(np.array([130.0, 5.0, 10.0]))
    empty = Histograms.empty(MODEL)
    for merged in (h.merge(empty), empty.merge(h), h.merge(empty, empty)):
        np.testing.assert_array_equal(merged.probs, h.probs)
        np.testing.assert_array_equal(merged.counts, h.counts)
    both = empty.merge(empty)
    assert not both.probs.any() and not both.counts.any()


@pytest.mark.parametrize(
    "other",
    [Histograms.empty(MODEL, bins=36), Histograms.empty(HINGE)],
    ids=["other_bins", "other_dofs"],
)
def test_merge_incompatible(other):
    with pytest.raises(HistogramError, match=r"cannot merge histograms of DOFs \[.*\] \(\d+ bins\) into"):
        Histograms.uniform(MODEL).merge(other)


# ---- circular statistics ------------------------------------------------------------------------------


def _concentrated(bins_on: list[int]) -> Histograms:
    h = Histograms.empty(MODEL)
    h.probs[:, bins_on] = 1.0 / len(bins_on)
    h.counts[:] = len(bins_on)
    return h


def test_means_in_range_coordinates_across_0_and_360():
    h = _concentrated(_bins((355, 360), (0, 5)))  # symmetric about 0/360
    a, b, w = h.means()
    assert b == pytest.approx(0.0, abs=1e-9)  # range -10..10
    assert w == pytest.approx(360.0, abs=1e-9)  # range 300..420: not 0, not 180
    assert a == 120.0  # outside 120..220: 0 is nearer to 120 (120 away) than to 220 (140 away)


def test_means_of_the_uniform_prior_are_the_range_midpoints():
    np.testing.assert_allclose(Histograms.uniform(MODEL).means(), [170, 0, 360], atol=1e-9)


def test_means_single_bin_and_nearer_end():
    h = _concentrated([200])
    # b: 200.5 is 149.5 from -10 (= 350) and 190.5 from 10; w: 200.5 is 99.5 from 300, 140.5 from 420 (= 60).
    assert h.means().tolist() == pytest.approx([200.5, -10.0, 300.0])


def test_means_without_direction_give_the_midpoint():
    assert Histograms.empty(MODEL).means().tolist() == [170, 0, 360]
    assert _concentrated(list(range(360))).means().tolist() == [170, 0, 360]


def test_stds_of_uniform_ranges():
    """Width w: w/sqrt(12) up to the 1° bin quantisation (sqrt((w² - 1)/12) for w bins)."""
    widths = np.array([100.0, 20.0, 120.0])
    s = Histograms.uniform(MODEL).stds()
    np.testing.assert_allclose(s, widths / math.sqrt(12), rtol=2e-3)
    np.testing.assert_allclose(s, np.sqrt((widths**2 - 1) / 12), rtol=1e-9)


def test_stds_single_bin_and_empty():
    assert np.all(_concentrated([359]).stds() < 1.0)
    assert np.all(_concentrated([359]).stds() == 0.0)
    np.testing.assert_allclose(Histograms.empty(MODEL).stds(), np.array([100.0, 20.0, 120.0]) / math.sqrt(12))


def test_stds_about_the_circular_mean_even_outside_the_range():
    """Mass in bin 220 (centre 220.5) is just above a = 120..220: the mean is clamped, the spread is not."""
    h = _concentrated([219, 220])  # centres 219.5 and 220.5
    assert h.means()[0] == 220.0
    assert h.stds()[0] == pytest.approx(0.5, abs=1e-9)


def test_stds_two_bins_across_0():
    """Half at 359.5, half at 0.5: mean 0, every deviation 0.5 (not 179.5)."""
    np.testing.assert_allclose(_concentrated([359, 0]).stds(), 0.5, atol=1e-9)


# ---- FORMATS §4 ------------------------------------------------------------------------------------


def _updated() -> Histograms:
    h = Histograms.uniform(MODEL, prior_weight=3)
    rng = np.random.default_rng(5)
    for a in rng.uniform(0, 360, (25, 3)):
        h.update(a)
    return h


@pytest.mark.parametrize("bins", [360, 4, 7])
def test_xml_round_trip(bins):
    h = Histograms.uniform(MODEL, prior_weight=2.5, bins=bins)
    for a in np.random.default_rng(bins).uniform(-400, 400, (11, 3)):
        h.update(a)
    again = Histograms.from_xml(h.to_xml(), MODEL)
    # Values are renormalised on reading: equal to the last bits.
    np.testing.assert_allclose(again.probs, h.probs, rtol=1e-15, atol=1e-17)
    np.testing.assert_array_equal(again.counts, h.counts)
    assert (again.names, again.model, again.bins) == (h.names, h.model, h.bins)
    np.testing.assert_array_equal(again.lower, h.lower)
    np.testing.assert_array_equal(again.upper, h.upper)


def test_xml_round_trip_keeps_special_characters_in_names():
    model = KinematicModel.from_xml(
        '<model name="a&amp;b&#9;c"><joint name="r"><dof axis="z" name="q&quot;&lt;&#10;" min="0" max="90"/>'
        '</joint><marker name="m" joint="r"/></model>'
    )
    again = Histograms.from_xml(Histograms.uniform(model).to_xml(), model)
    assert ET.fromstring(again.to_xml()).get("model") == "a&b\tc"
    assert again.names == ('q"<\n',)


def test_xml_format():
    h = _updated()
    text = h.to_xml()
    root = ET.fromstring(text)
    assert root.tag == "histograms" and root.attrib == {"model": "h", "bins": "360"}
    dofs = list(root)
    assert [(d.tag, d.get("name"), d.get("count")) for d in dofs] == [
        ("dof", "a", "28"), ("dof", "b", "28"), ("dof", "w", "28"),
    ]
    for d, p in zip(dofs, h.probs, strict=True):
        values = d.text.split()
        assert len(values) == 360
        np.testing.assert_allclose([float(v) for v in values], p, rtol=0, atol=0)
    assert not re.search(r"[eE]", "".join(d.text for d in dofs))


def test_xml_tiny_values_have_no_exponent():
    h = Histograms.uniform(HINGE, bins=4, prior_weight=1e20)
    h.update(np.array([300.0]))  # bin 3 gets 1/(1e20 + 1) ~ 1e-20
    text = h.to_xml()
    assert "0.00000000000000000001" in text and not re.search(r"\d[eE][-+]?\d", text)
    again = Histograms.from_xml(text, HINGE)
    np.testing.assert_allclose(again.probs, h.probs, rtol=1e-15, atol=0)
    assert again.counts.tolist() == [1e20]


def test_xml_count_zero_is_read():
    text = '<histograms model="hinge" bins="4"><dof name="q" count="0">0 0 0 0</dof></histograms>'
    h = Histograms.from_xml(text, HINGE)
    assert h.counts.tolist() == [0] and not h.probs.any()


def test_xml_default_bins_and_whitespace():
    values = "\n".join(["0.5", "0.5"] + ["0"] * 358)
    text = f'<histograms model="hinge"><dof name="q" count="2">\n{values}\t</dof></histograms>'
    h = Histograms.from_xml(text, HINGE)
    assert h.bins == 360 and h.probs[0, :2].tolist() == [0.5, 0.5]


def _hist_xml(dofs: str, bins: str = "4", root: str = "histograms") -> str:
    return f'<{root} model="h" bins="{bins}">{dofs}</{root}>'


A = '<dof name="a" count="2">0.25 0.25 0.5 0</dof>'
B = '<dof name="b" count="2">1 0 0 0</dof>'
W = '<dof name="w" count="2">0 0 0 1</dof>'

INVALID = {
    "unknown_dof": (_hist_xml(A + B + W + '<dof name="zzz" count="1">1 0 0 0</dof>'),
                    "dof 'zzz' is not a rotational DOF of model 'h'"),
    "translational_dof": (_hist_xml(A + B + W + '<dof name="tx" count="1">1 0 0 0</dof>'),
                          "dof 'tx' is not a rotational DOF"),
    "missing_dof": (_hist_xml(A + W), r"no histogram for DOF\(s\) b"),
    "duplicate_dof": (_hist_xml(A + B + W + A), "dof 'a' appears twice"),
    "too_few_values": (_hist_xml(A.replace("0.5 0", "0.5") + B + W), "dof 'a': expected 4 values, got 3"),
    "too_many_values": (_hist_xml(A + B.replace("1 0", "1 0 0") + W), "dof 'b': expected 4 values, got 5"),
    "negative_value": (_hist_xml(A.replace("0.25 0.25 0.5 0", "0.75 -0.25 0.5 0") + B + W),
                       "dof 'a': values must be non-negative"),
    "nan_value": (_hist_xml(A.replace("0.5 0", "0.5 nan") + B + W),
                  "dof 'a': values must be non-negative numbers"),
    "not_summing_to_1": (_hist_xml(A.replace("0.5 0", "0.5 0.1") + B + W),
                         "dof 'a': values sum to 1.1, not 1"),
    "all_zero_with_count": (_hist_xml(A + B.replace("1 0", "0 0") + W), "dof 'b': values sum to 0, not 1"),
    "non_numeric_value": (_hist_xml(A.replace("0.5 0", "0.5 x") + B + W), "dof 'a': could not convert"),
    "digit_separator": (_hist_xml(A.replace("0.5 0", "0.5 0_0") + B + W), "dof 'a': could not convert"),
    "non_numeric_count": (_hist_xml(A.replace('count="2"', 'count="many"') + B + W),
                          "dof 'a': could not convert string to float: 'many'"),
    "negative_count": (_hist_xml(A.replace('count="2"', 'count="-1"') + B + W),
                       "dof 'a': count must be a non-negative number"),
    "infinite_count": (_hist_xml(A.replace('count="2"', 'count="inf"') + B + W),
                       "dof 'a': count must be a non-negative number"),
    "missing_count": (_hist_xml(A.replace(' count="2"', "") + B + W),
                      "dof 'a': count must be a non-negative"),
    "bins_not_whole": (_hist_xml(A + B + W, bins="4.5"), "bins='4.5' is not a whole number"),
    "bins_zero": (_hist_xml(A + B + W, bins="0"), "bins=0 must be at least 1"),
    "bins_huge": (_hist_xml(A + B + W, bins="1000000000000"),
                  r"bins=1000000000000 is more than 3600 \(MAX_BINS\)"),
    "wrong_root": (_hist_xml(A + B + W, root="histogram"),
                   "root element is <histogram>, expected <histograms>"),
    "malformed": (_hist_xml(A + B + W)[:-3], "not well-formed XML"),
    "dtd": ('<!DOCTYPE histograms SYSTEM "h.dtd">' + _hist_xml(A + B + W), "refused unsafe XML"),
    "entity": ('<!DOCTYPE histograms [<!ENTITY one "1">]>' + _hist_xml(A + B.replace("1 0", "&one; 0") + W),
               "refused unsafe XML"),
    "external_entity": ('<!DOCTYPE histograms [<!ENTITY x SYSTEM "file:///etc/passwd">]>'
                        + _hist_xml(A + B + W).replace('model="h"', 'model="&x;"'), "refused unsafe XML"),
}


def test_the_read_cases_start_from_a_valid_file():
    h = Histograms.from_xml(_hist_xml(A + B + W), MODEL)
    assert h.bins == 4 and h.probs[0].tolist() == [0.25, 0.25, 0.5, 0] and h.counts.tolist() == [2, 2, 2]


@pytest.mark.parametrize(("text", "match"), INVALID.values(), ids=INVALID.keys())
def test_invalid_histograms(text, match):
    with pytest.raises(HistogramError, match=match):
        Histograms.from_xml(text, MODEL)


def test_unreadable_histogram_file(tmp_path):
    with pytest.raises(HistogramError, match="cannot read histogram file"):
        Histograms.from_xml(tmp_path / "missing.xml", MODEL)


def test_uniform_prior_keeps_partly_covered_edge_bins():
    """min=120.7, max=130.2: bins 120 (120.7..121) and 130 (130..130.2) overlap the range."""
    model = KinematicModel.from_xml(
        '<model name="f"><joint name="r"><dof axis="z" name="q" min="120.7" max="130.2"/></joint>'
        '<marker name="m" joint="r"/></model>'
    )
    probs = Histograms.uniform(model).probs[0]
    assert np.flatnonzero(probs).tolist() == list(range(120, 131))
