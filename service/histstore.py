"""Histograms stored exactly: probabilities and counts as ``.npz`` (float64, bit for bit).

Chunk observations and archive versions are merged by counts later; the
6-decimal XML of FORMATS §4 would round them, so XML is only rendered for
downloads.
"""

from __future__ import annotations

import io

import numpy as np

from core.histogram import Histograms
from core.model import KinematicModel
from service.storage import Storage


def save(storage: Storage, key: str, histograms: Histograms) -> None:
    buffer = io.BytesIO()
    np.savez(buffer, probs=histograms.probs, counts=histograms.counts,
             names=np.array(histograms.names))
    storage.put(key, [buffer.getvalue()])


def load(storage: Storage, key: str, model: KinematicModel) -> Histograms:
    """The histograms saved under ``key``, for ``model`` (their DOFs must be the model's)."""
    with storage.open(key) as f, np.load(f) as data:
        probs, counts, names = data["probs"], data["counts"], tuple(data["names"].tolist())
    out = Histograms.empty(model, bins=probs.shape[1])
    if names != out.names:
        raise ValueError(f"stored histograms {key} are of DOFs {list(names)}, not {list(out.names)}")
    out.probs[:] = probs
    out.counts[:] = counts
    return out
