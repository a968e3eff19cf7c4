"""Argument checks shared by the renderer, the movement generator and the files they write:
each raises ValueError naming the parameter, at the public entry."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from core.model import KinematicModel
    from core.rig import Rig


def check_trajectory(trajectory: np.ndarray, model: KinematicModel) -> np.ndarray:
    """The postures as a contiguous float64 array (T, D), T >= 1, every value finite."""
    q = np.asarray(trajectory, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != len(model.dofs) or len(q) == 0:
        raise ValueError(
            f"trajectory must have shape (T, D) with T >= 1 and D={len(model.dofs)}, "
            f"got {np.shape(trajectory)}"
        )
    if not np.all(np.isfinite(q)):
        raise ValueError("trajectory contains a value that is not a finite number")
    return np.ascontiguousarray(q)


def check_frame_size(frame_size: tuple[int, int]) -> tuple[int, int]:
    """(width, height) as two positive ints."""
    try:
        width, height = frame_size
    except (TypeError, ValueError):
        raise ValueError(f"frame_size must be (width, height), got {frame_size!r}") from None
    for v in (width, height):
        if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < 1:
            raise ValueError(f"frame_size must be two positive integers, got {frame_size!r}")
    return int(width), int(height)


def check_positive(name: str, value: float) -> float:
    """``value`` as a float, finite and > 0."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.number) or not (
        math.isfinite(value) and value > 0
    ):
        raise ValueError(f"{name} must be a positive number, got {value!r}")
    return float(value)


def check_non_negative(name: str, value: float) -> float:
    """``value`` as a float, finite and >= 0."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.number) or not (
        math.isfinite(value) and value >= 0
    ):
        raise ValueError(f"{name} must be a number >= 0, got {value!r}")
    return float(value)


def roi_rect(rig: Rig, index: int, width: int, height: int) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) of a view's roi, end exclusive; the whole frame without roi."""
    view = rig.views[index]
    if view.roi is None:
        return (0, 0, width, height)
    x, y, w, h = view.roi
    if x + w > width or y + h > height:
        raise ValueError(
            f"roi {list(view.roi)} of view '{view.name}' lies outside the {width}×{height} frame"
        )
    return (x, y, x + w, y + h)
