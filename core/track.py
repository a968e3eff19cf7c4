"""Optional root tracking (paper §2.1): the root marker followed by next neighbour in every view.

When the animal's body moves, the model's root is not fixed in the image. The
paper marks the root with a marker, gives its position in every view for the
first image, and follows it from image to image by next neighbour; the tracked
position minus where the rig projects the root marker is an offset added to
every projection of that view (``core.error``), so the fit of every image stays
independent.

Tracking itself is sequential (each image starts from the last position), so a
sequence is tracked once, before its images are fitted in chunks, and every
chunk reads its images' offsets.

The root marker must sit at the origin of the root joint, and the root must not
have translational DOFs: then its projection does not depend on the posture,
and the offset is the root's displacement in that view alone.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from core.error import Detections
from core.model import KinematicModel
from core.rig import Rig

__all__ = ["RootTracking", "root_reference", "track_root"]


@dataclass(frozen=True)
class RootTracking:
    """How to track the root.

    marker : name of the model marker at the root joint's origin.
    start : its (u, v) position in every view of the first image, full-frame pixels;
        None starts where the rig projects it (no offset at the first image).
    max_jump_px : a view's nearest detection farther than this from the last
        position is not the root marker (occluded): the position is kept.
    """

    marker: str
    start: tuple[tuple[float, float], ...] | None = None
    max_jump_px: float = 20.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.max_jump_px) and self.max_jump_px > 0):
            raise ValueError(f"max_jump_px must be a positive number, got {self.max_jump_px!r}")
        if self.start is not None:
            start = np.asarray(self.start, dtype=np.float64)
            if start.ndim != 2 or start.shape[1] != 2 or not np.all(np.isfinite(start)):
                raise ValueError(f"start must be one finite (u, v) per view, got {self.start!r}")


def root_reference(model: KinematicModel, rig: Rig, marker: str) -> np.ndarray:
    """(V, 2) float64 pixels: where the rig projects the root marker, whatever the posture.

    Raises ValueError if the marker is unknown, not at the root joint's origin,
    or the root has translational DOFs.
    """
    found = [m for m in model.markers if m.name == marker]
    if not found:
        raise ValueError(f"root marker '{marker}' is not a marker of model '{model.name}'")
    root = next(j.name for j in model.joints if j.parent is None)
    if found[0].joint != root or any(found[0].position):
        raise ValueError(
            f"root marker '{marker}' must sit at the origin of the root joint '{root}' "
            "(its projection must not depend on the posture)"
        )
    if not np.all(model.rotational):
        raise ValueError("root tracking needs a root without translational DOFs (tx, ty, tz)")
    index = [m.name for m in model.markers].index(marker)
    world = model.marker_positions(0.5 * (model.lower + model.upper))
    return rig.project(world)[:, index, :]


def track_root(
    images: Iterable[Detections],
    *,
    reference: np.ndarray,
    tracking: RootTracking,
) -> np.ndarray:
    """Offsets of every image by next-neighbour tracking of the root marker in every view.

    Parameters
    ----------
    images : Detections of the images in sample order, from the first image on.
    reference : (V, 2) from :func:`root_reference`.
    tracking : the marker's start positions and the largest jump.

    Returns
    -------
    ndarray of shape (N, V, 2), float64, pixels to add to each view's projections.
    """
    ref = np.asarray(reference, dtype=np.float64)
    position = ref.copy() if tracking.start is None else np.array(tracking.start, dtype=np.float64)
    if position.shape != ref.shape:
        raise ValueError(f"start has {len(position)} positions for a rig of {len(ref)} views")
    jump2 = tracking.max_jump_px**2
    offsets = []
    for det in images:
        for v in range(len(ref)):
            position[v] = _next_neighbour(det.view(v), position[v], jump2)
        offsets.append(position - ref)
    return np.array(offsets).reshape(-1, len(ref), 2)


def _next_neighbour(points: np.ndarray, last: np.ndarray, jump2: float) -> np.ndarray:
    """The detection nearest to ``last`` if within the jump, else ``last`` (marker lost)."""
    if len(points) == 0:
        return last
    d2 = np.sum((points - last) ** 2, axis=1)
    k = int(np.argmin(d2))
    return points[k] if d2[k] <= jump2 else last

