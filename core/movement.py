"""Natural movements: posture trajectories like the paper's §3.2 test video, for the renderer.

Concatenated sequences of smooth minimum-jerk movements between random key postures,
each with one fast extension (a kick), every marker kept inside its view.
"""

from __future__ import annotations

import numpy as np

from core import _checks
from core.model import KinematicModel
from core.rig import Rig

__all__ = ["natural_movements"]


def natural_movements(
    model: KinematicModel,
    rig: Rig,
    n_samples: int,
    *,
    rng: np.random.Generator,
    n_sequences: int = 10,
    fps: float = 50.0,
    margin_px: float = 8.0,
    frame_size: tuple[int, int] = (720, 576),
) -> np.ndarray:
    """A trajectory like the paper's §3.2 test video: sequences of smooth movements with kicks.

    ``n_samples`` are split into ``n_sequences`` sequences of (almost) equal
    length, ``np.array_split`` sizes, concatenated with a jump between them (the
    next sequence starts at least a quarter of some DOF's usable range away from
    where the last one ended). Within a sequence the posture moves smoothly,
    by minimum-jerk interpolation, between random key postures 0.2–0.5 s apart
    (each key a random step from the last). Each sequence contains one fast
    extension: one or two rotational DOFs (any DOFs if the model has no
    rotation) are first brought near one end of their usable range and then
    swept to the other end (at least 70 % of it) within 2–4 samples, like a
    locust kick.

    Every sample keeps each DOF at least ``min(3, 10 % of its range)`` degrees
    (5 % of the range for translations) inside its limits, and every marker
    projection inside its view's roi (or the frame) with ``margin_px`` to spare;
    key postures whose movement would leave it are drawn again.

    Parameters
    ----------
    model : KinematicModel
    rig : Rig
    n_samples : int
        T, number of samples (frames or fields), >= 1.
    rng : numpy.random.Generator
    n_sequences : int, default 10
        Number of sequences, >= 1; reduced so that each has at least 10 samples
        (a single sequence shorter than 3 samples has no kick).
    fps : float, default 50.0
        Samples per second, used for the 0.2–0.5 s key spacing.
    margin_px : float, default 8.0
        Distance in pixels every marker projection keeps from its roi's border.
    frame_size : (width, height), default (720, 576)
        Frame size, the bounds of views without roi.

    Returns
    -------
    ndarray of shape (T, D), float64
        Postures, model-file DOF order (degrees, model units).

    Raises
    ------
    ValueError
        On invalid arguments, or if no posture (or no kick) keeps the markers in the rois.
    """
    if isinstance(n_samples, bool) or not isinstance(n_samples, int | np.integer) or n_samples < 1:
        raise ValueError(f"n_samples must be an integer >= 1, got {n_samples!r}")
    if isinstance(n_sequences, bool) or not isinstance(n_sequences, int | np.integer) or (
        n_sequences < 1
    ):
        raise ValueError(f"n_sequences must be an integer >= 1, got {n_sequences!r}")
    rate = _checks.check_positive("fps", fps)
    margin = _checks.check_non_negative("margin_px", margin_px)
    width, height = _checks.check_frame_size(frame_size)
    space = _PostureSpace(model, rig, margin, width, height)
    n_seq = max(1, min(int(n_sequences), int(n_samples) // _MIN_SEQUENCE))
    sizes = [len(a) for a in np.array_split(np.arange(int(n_samples)), n_seq)]
    sequences: list[np.ndarray] = []
    for size in sizes:
        previous = sequences[-1][-1] if sequences else None
        sequences.append(_sequence(size, space, rng, rate, previous))
    return np.concatenate(sequences)


_MIN_SEQUENCE = 10  # samples
_KEY_SPACING_S = (0.2, 0.5)
_JUMP = 0.25  # fraction of a DOF's usable range the next sequence starts away
_COCKED = 0.15  # the kicking DOF starts within this fraction of one end of its usable range
_ATTEMPTS = 200


class _PostureSpace:
    """Usable DOF box and the roi test of postures."""

    def __init__(self, model: KinematicModel, rig: Rig, margin: float, width: int, height: int):
        self.model, self.rig = model, rig
        span = model.upper - model.lower
        inset = np.where(model.rotational, np.minimum(3.0, 0.1 * span), 0.05 * span)
        self.lo, self.hi = model.lower + inset, model.upper - inset
        self.span = self.hi - self.lo
        rects = np.array([_checks.roi_rect(rig, i, width, height) for i in range(len(rig.views))], float)
        self.bounds_lo = rects[:, None, :2] + margin  # (V, 1, 2)
        self.bounds_hi = rects[:, None, 2:] - margin
        kickers = np.flatnonzero(model.rotational)
        self.kickers = kickers if len(kickers) else np.arange(len(model.dofs))

    def valid(self, q: np.ndarray) -> bool:
        """True if every posture of ``q`` (n, D) projects every marker inside the rois."""
        proj = self.rig.project(self.model.marker_positions(np.atleast_2d(q)))  # (n, V, M, 2)
        return bool(
            np.all(np.isfinite(proj))
            and np.all(proj >= self.bounds_lo)
            and np.all(proj <= self.bounds_hi)
        )

    def random_posture(self, rng: np.random.Generator) -> np.ndarray:
        return self.lo + self.span * rng.random(len(self.lo))

    def step(self, q: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """A random key posture around ``q``: uniform within ±half the usable range, in the box."""
        lo = np.maximum(self.lo, q - 0.5 * self.span)
        hi = np.minimum(self.hi, q + 0.5 * self.span)
        return lo + (hi - lo) * rng.random(len(q))


def _min_jerk(q0: np.ndarray, q1: np.ndarray, n: int) -> np.ndarray:
    """(n + 1, D) postures from q0 to q1 in n sample intervals, minimum-jerk profile."""
    s = np.arange(n + 1, dtype=np.float64) / n
    profile = s**3 * (10.0 - 15.0 * s + 6.0 * s * s)
    return q0 + (q1 - q0) * profile[:, None]


def _sequence(
    size: int,
    space: _PostureSpace,
    rng: np.random.Generator,
    fps: float,
    previous: np.ndarray | None,
) -> np.ndarray:
    for _ in range(20):
        seq = _try_sequence(size, space, rng, fps, previous)
        if seq is not None:
            return seq
    raise ValueError(
        "could not generate a movement that keeps every marker inside its view's roi "
        "(rois too small for the model, or margin_px too large)"
    )


def _try_sequence(
    size: int,
    space: _PostureSpace,
    rng: np.random.Generator,
    fps: float,
    previous: np.ndarray | None,
) -> np.ndarray | None:
    lo_gap = max(2, round(_KEY_SPACING_S[0] * fps))
    hi_gap = max(lo_gap, round(_KEY_SPACING_S[1] * fps))
    out = np.empty((size, len(space.lo)))
    kick = min(int(rng.integers(2, 5)), size - 1) if size >= 3 else 0
    # The kick runs from sample ks to ks + kick; ks leaves room for a smooth approach.
    latest = size - 1 - kick
    ks = int(rng.integers(lo_gap, latest + 1)) if kick and latest >= lo_gap else 0
    if kick and ks == 0:  # the sequence starts cocked
        q = _cocked_and_kick(out, 0, 0, kick, None, space, rng, previous)
        if q is None:
            return None
        t = kick
    else:
        q = _start_posture(space, rng, previous)
        if q is None:
            return None
        out[0], t = q, 0
        if kick:
            keys = _key_times(0, ks, lo_gap, hi_gap, rng)
            for t1 in keys[:-1]:
                q = _smooth_segment(out, t, t1, q, space, rng)
                t = t1
            q = _cocked_and_kick(out, t, ks, kick, q, space, rng, None)
            if q is None:
                return None
            t = ks + kick
    while t < size - 1:
        t1 = t + int(rng.integers(lo_gap, hi_gap + 1))
        q = _smooth_segment(out, t, t1, q, space, rng, stop=size - 1)
        t = min(t1, size - 1)
    return out


def _key_times(t0: int, t1: int, lo_gap: int, hi_gap: int, rng: np.random.Generator) -> list[int]:
    """Key sample times after ``t0`` ending exactly at ``t1``; no gap shorter than ``lo_gap``."""
    if t1 <= t0:
        return [t0]
    times = [t0]
    while times[-1] < t1:
        times.append(times[-1] + int(rng.integers(lo_gap, hi_gap + 1)))
    times[-1] = t1
    if len(times) > 2 and times[-1] - times[-2] < lo_gap:
        del times[-2]
    return times[1:]


def _smooth_segment(
    out: np.ndarray,
    t0: int,
    t1: int,
    q0: np.ndarray,
    space: _PostureSpace,
    rng: np.random.Generator,
    stop: int | None = None,
) -> np.ndarray:
    """Fill ``out[t0:t1+1]`` (clipped at ``stop``) moving from q0 to a valid random key."""
    end = t1 if stop is None else min(t1, stop)
    q1, path = q0, np.repeat(q0[None], t1 - t0 + 1, axis=0)  # holding still is always valid
    for _ in range(_ATTEMPTS):
        cand = space.step(q0, rng)
        trial = _min_jerk(q0, cand, t1 - t0)
        if space.valid(trial[: end - t0 + 1]):
            q1, path = cand, trial
            break
    out[t0 : end + 1] = path[: end - t0 + 1]
    return q1 if end == t1 else path[end - t0]


def _start_posture(
    space: _PostureSpace, rng: np.random.Generator, previous: np.ndarray | None
) -> np.ndarray | None:
    """A valid random posture; away from ``previous`` (a jump) when given."""
    for _ in range(_ATTEMPTS * 5):
        cand = space.random_posture(rng)
        if _jumps(cand, previous, space) and space.valid(cand):
            return cand
    return None


def _jumps(q: np.ndarray, previous: np.ndarray | None, space: _PostureSpace) -> bool:
    return previous is None or bool(np.any(np.abs(q - previous) >= _JUMP * space.span))


def _cocked_and_kick(
    out: np.ndarray,
    t0: int,
    ks: int,
    kick: int,
    q0: np.ndarray | None,
    space: _PostureSpace,
    rng: np.random.Generator,
    previous: np.ndarray | None,
) -> np.ndarray | None:
    """Fill ``out[t0:ks+kick+1]``: approach a cocked posture at ``ks``, then sweep (the kick).

    One or two kicking DOFs are brought within ``_COCKED`` of one end of their
    usable range and swept to within ``_COCKED`` of the other end in ``kick``
    sample intervals. With ``q0`` None the sequence starts cocked (``t0 == ks ==
    0``) and the cocked posture must jump away from ``previous``. Returns the
    kicked posture, or None if no valid kick was found.
    """
    for _ in range(_ATTEMPTS * 2):
        n_dofs = 1 if len(space.kickers) == 1 or rng.random() < 0.5 else 2
        dofs = rng.choice(space.kickers, size=n_dofs, replace=False)
        up = rng.random(n_dofs) < 0.5  # sweep towards the upper limit
        near = _COCKED * rng.random(n_dofs)
        far = 1.0 - _COCKED * rng.random(n_dofs)
        cocked = space.random_posture(rng) if q0 is None else space.step(q0, rng)
        cocked[dofs] = space.lo[dofs] + space.span[dofs] * np.where(up, near, 1.0 - near)
        kicked = cocked.copy()
        kicked[dofs] = space.lo[dofs] + space.span[dofs] * np.where(up, far, 1.0 - far)
        if q0 is None:
            if not _jumps(cocked, previous, space):
                continue
            approach = cocked[None]
        else:
            approach = _min_jerk(q0, cocked, ks - t0)
        sweep = _min_jerk(cocked, kicked, kick)
        if space.valid(approach) and space.valid(sweep):
            out[t0 : ks + 1] = approach
            out[ks : ks + kick + 1] = sweep
            return kicked
    return None
