"""Uploading a model whose markers cannot determine some DOF in any posture: stored as any
other, with a warning that names the DOFs and the fix (docs/API.md, FORMATS §1)."""

from __future__ import annotations

import pytest

from core.examples import LOCUST

pytestmark = [pytest.mark.service]

XML = (LOCUST / "model.xml").read_text()
# A claw joint below the tarsus that turns and carries no marker.
CLAW = XML.replace("  <marker", '  <joint name="claw" parent="tarsus"><offset x="3"/>'
                   '<dof axis="z" name="claw_z" min="-30" max="30"/></joint>\n  <marker', 1)


def _upload(client, xml: str):
    return client.post("/models", content=xml.encode(), headers={"Content-Type": "application/xml"})


def test_a_model_with_an_undetermined_dof_is_stored_with_a_warning(embedded):
    lab = embedded.create_lab("warned")
    plain, claw = _upload(lab, XML), _upload(lab, CLAW)
    assert (plain.status_code, claw.status_code) == (201, 201), claw.text
    assert plain.json()["warnings"] == []
    assert claw.json()["warnings"] == ["claw_z moves no marker: add a marker to segment claw"]
    assert claw.json()["dofs"][-1] == "claw_z"
