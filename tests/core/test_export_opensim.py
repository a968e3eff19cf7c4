"""OpenSim's own readers load our .mot and .trc (the opensim extra, ~380 MB).

Deselected by the default ``-m 'not opensim'``; the last step of ``.ci/run`` installs the
extra and selects them, where a missing opensim fails the import below.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_export import MODEL, angles_table

from core.export import marker_trajectories, write_mot, write_trc

pytestmark = [pytest.mark.opensim, pytest.mark.slow]


def test_opensim_reads_the_mot_as_a_table(tmp_path):
    import opensim

    table = angles_table(MODEL)
    write_mot(tmp_path / "angles.mot", table, MODEL)
    read = opensim.TimeSeriesTable(str(tmp_path / "angles.mot"))
    assert list(read.getColumnLabels()) == MODEL.dof_names
    assert read.getTableMetaDataAsString("inDegrees") == "yes"
    np.testing.assert_allclose(list(read.getIndependentColumn()), table.times, atol=5e-7)
    values = np.array([[read.getRowAtIndex(i)[j] for j in range(len(MODEL.dofs))]
                       for i in range(read.getNumRows())])
    np.testing.assert_allclose(values, table.dofs, atol=5e-7)


@pytest.mark.parametrize(("units", "scale"), [("model", 1.0), ("m", 1e-3)])
def test_opensim_reads_the_trc_as_a_marker_table(tmp_path, units, scale):
    import opensim

    table = angles_table(MODEL)
    write_trc(tmp_path / "markers.trc", table, MODEL, units=units)
    read = opensim.TimeSeriesTableVec3(str(tmp_path / "markers.trc"))
    assert list(read.getColumnLabels()) == [m.name for m in MODEL.markers]
    assert read.getTableMetaDataAsString("Units") == ("mm" if units == "model" else "m")
    points = np.array([[[read.getRowAtIndex(i)[j][k] for k in range(3)] for j in range(len(MODEL.markers))]
                       for i in range(read.getNumRows())])
    np.testing.assert_allclose(points, marker_trajectories(table, MODEL) * scale, atol=5e-7 * scale)
