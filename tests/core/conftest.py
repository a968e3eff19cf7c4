"""Fixtures shared by the tests of the fitting modules (error, anneal, refine, fit, _kernels)."""

from __future__ import annotations

import pytest

from core.examples import LOCUST
from core.model import KinematicModel
from core.rig import Rig


@pytest.fixture(scope="module")
def locust() -> tuple[KinematicModel, Rig]:
    """The locust hind-leg example's model and two-view rig (a module may define its own)."""
    return (
        KinematicModel.from_xml(LOCUST / "model.xml"),
        Rig.from_json(LOCUST / "rig.json"),
    )
