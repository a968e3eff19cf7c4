"""The paper's two examples, shipped with the package so that an installed ``mocap`` finds them.

- ``locust_hind_leg``: the locust hind leg of Fig. 5, its model and the rigs of one mirror
  video (``rig.json``), three pinhole cameras (``rig_pinhole.json``) and a DLT calibration
  (``cal_dltCoefs.csv``, imported as ``rig_dlt.json``);
- ``stick_insect_front_leg``: the stick insect front leg of Fig. 7, model and rig.

>>> sorted(p.name for p in (EXAMPLES / "stick_insect_front_leg").iterdir())
['model.xml', 'rig.json']
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["EXAMPLES", "LOCUST"]

EXAMPLES = Path(__file__).resolve().parent  # one folder per example
LOCUST = EXAMPLES / "locust_hind_leg"  # the example `mocap demo`, the tests and the README use
