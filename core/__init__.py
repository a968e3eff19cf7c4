"""The science of model-based motion capture, with no web and no database.

One concept per module, named as the paper names it: the kinematic model
(``model``, §2.1), the camera rig (``rig``, Eq. 3), joint-angle histograms
(``histogram``, Eq. 4), the error function (``error``, Eq. 5), Simulated
Annealing (``anneal``, Eq. 6) with local refinement (``refine``), depth
ambiguities (``ambiguity``), fitting an image (``fit``, §3.2), a sequence's
steps shared by ``mocap fit`` and the workers (``sequence``, §4), marker
detection (``detect``), de-interlacing (``fields``), video files (``video``),
root tracking (``track``), a video job, its plan and its result files
(``pipeline``), results files (``results``), the synthetic renderer
(``render``) and its movements (``movement``), gathered with the truth files by
``synth``, the lab's XML files (``xmlio``) and the paper's examples
(``examples``). The names below are the public ones; compiled kernels live in
``_kernels`` (fitting), ``_detect_kernels`` and ``_histogram_kernels``.
"""

from core.anneal import AnnealParams, anneal
from core.detect import DetectorParams, detect
from core.error import Detections, view_error
from core.fields import detect_fields
from core.fit import FitParams, ImageFit, Status, reanalyse_image
from core.histogram import HistogramError, Histograms
from core.model import KinematicModel, ModelError
from core.pipeline import FitJob, VideoSource, run_fit
from core.rig import Rig, RigError
from core.sequence import fit_chunk, fit_sequence
from core.track import RootTracking
from core.video import VideoError, VideoSet, probe

__all__ = [
    "AnnealParams",
    "Detections",
    "DetectorParams",
    "FitJob",
    "FitParams",
    "HistogramError",
    "Histograms",
    "ImageFit",
    "KinematicModel",
    "ModelError",
    "Rig",
    "RigError",
    "RootTracking",
    "Status",
    "VideoError",
    "VideoSet",
    "VideoSource",
    "anneal",
    "detect",
    "detect_fields",
    "fit_chunk",
    "fit_sequence",
    "probe",
    "reanalyse_image",
    "run_fit",
    "view_error",
]
