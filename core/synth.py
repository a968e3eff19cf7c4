"""Synthetic clips with known postures (paper §3.2), by the modules that make them:

- :func:`~core.movement.natural_movements` makes a trajectory like the paper's:
  concatenated sequences of smooth movements with fast extensions (kicks);
- :func:`~core.render.render_frames` draws its frames (lazily, one at a time);
- :func:`~core.video.write_video` stores them losslessly (FFV1), bit-exact when read back;
- :func:`~core.results.write_truth_csv` / :func:`~core.results.read_truth_csv` store the
  true postures (FORMATS §3 columns ``sample,frame,field,time_s,<dofs>``).

This module gathers them under one name for the code and notebooks that render clips.
"""

from __future__ import annotations

from core.movement import natural_movements
from core.render import render_frames
from core.results import read_truth_csv, write_truth_csv
from core.video import write_video

__all__ = [
    "natural_movements",
    "read_truth_csv",
    "render_frames",
    "write_truth_csv",
    "write_video",
]
