"""Detection and fit on footage drawn another way: an independent renderer, then `mocap fit`.

    python bench/footage.py [--subject locust|hexapod|rat|spider|all] [--variant NAME|all]
        [--frames 60] [--seed 1] [--threshold auto|otsu|100]

``core.synth`` draws flat anti-aliased discs on a dark, lightly noisy background; a lab's
footage, or another implementation's renders of the same contract, look otherwise. This
renderer was written by someone who had not worked on the detector, from the file contract
alone: it uses only forward kinematics (``KinematicModel.marker_positions``) and projection
(``Rig.project``), which FORMATS §1 and §2 define; how a marker looks is its own
(:data:`VARIANTS`). Postures are a sinusoid per DOF about the middle of its range (a quarter
of the range in amplitude, periods of 30-90 images). Every run writes raw grey AVI (MJPG
where a variant says so), runs ``mocap fit`` on it with default settings (and
``--threshold`` where given), and prints per-DOF RMSE (median and worst), the share of images with every
DOF within 5°, images more than 10° off (how many of those are ``ok``, and how many of these
have no alternative: issue 13's "never"), status counts,
ambiguous images and the estimated marker diameter. Files go to ``bench/out/footage/``.
"""

from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.animals import FAR_OFF_DEG, angle_errors, far_off_unflagged  # noqa: E402
from core.error import fused_marker_diameter  # noqa: E402
from core.examples import LOCUST  # noqa: E402
from core.model import KinematicModel  # noqa: E402
from core.rig import Rig  # noqa: E402

OUT = ROOT / "bench" / "out" / "footage"
SUBJECTS = {"locust": LOCUST, "hexapod": ROOT / "bench" / "subjects" / "hexapod",
            "rat": ROOT / "bench" / "subjects" / "rat", "spider": ROOT / "bench" / "subjects" / "spider"}
# How markers are drawn. profile: 'disc' (anti-aliased, 8×8 supersampling), 'hard' (a pixel is
# on if its centre is inside), 'gauss' (peak · exp(-r²/2σ²), as a retroreflective marker's
# glow). diam, sigma: px. bg, bg_sigma, peak: grey levels. blur: sub-positions averaged over
# the middle two thirds of the interval between images (motion blur). ghosts per view and
# image; occlude: the chance per image that one (view, marker) is not drawn; blank: images
# drawn without markers (lights off, the animal out of view).
VARIANTS = {
    "baseline": dict(profile="disc", diam=5.0),
    "hard_disc": dict(profile="hard", diam=5.0),
    "gauss": dict(profile="gauss", sigma=1.5, peak=255),
    "disc3": dict(profile="disc", diam=3.0),
    "disc9": dict(profile="disc", diam=9.0),
    "noisy_disc": dict(profile="disc", diam=5.0, bg=40, bg_sigma=10, peak=180),
    "noisy_gauss": dict(profile="gauss", sigma=1.5, bg=40, bg_sigma=10, peak=180),
    "dim_gauss": dict(profile="gauss", sigma=1.5, bg=40, bg_sigma=10, peak=120),
    "mjpg": dict(profile="disc", diam=5.0, codec="MJPG"),
    "blur3": dict(profile="disc", diam=5.0, blur=3),
    "blur9": dict(profile="disc", diam=5.0, blur=9),
    "lit_background": dict(profile="disc", diam=5.0, bg=110, bg_sigma=10, peak=255),
    "ghosts_hidden": dict(profile="disc", diam=5.0, ghosts=2, occlude=0.2),
    "blank_first": dict(profile="disc", diam=5.0, blur=3, blank=(0,)),
}


def postures(model: KinematicModel, n: int, rng: np.random.Generator):
    """q(t): (…, D) postures at (fractional) image times t, a sinusoid per DOF about the middle
    of its range, a quarter of the range in amplitude, periods of 30-90 images."""
    middle, span = (model.lower + model.upper) / 2, model.upper - model.lower
    period, phase = rng.uniform(30, 90, len(middle)), rng.uniform(0, 2 * np.pi, len(middle))

    def q(t: np.ndarray) -> np.ndarray:
        return middle + 0.25 * span * np.sin(2 * np.pi * np.asarray(t, float)[..., None] / period + phase)
    return q


def frame_sizes(rig: Rig) -> dict[int, tuple[int, int]]:
    """(width, height) per video: covering every roi, twice a pinhole's principal point, and at
    least PAL (720×576) for a video of affine or DLT views."""
    sizes: dict[int, tuple[int, int]] = {}
    for view in rig.views:
        w, h = (view.roi[0] + view.roi[2], view.roi[1] + view.roi[3]) if view.roi is not None else (0, 0)
        if view.projection["type"] == "pinhole":
            k = view.projection["K"]
            w, h = max(w, round(2 * k[0][2])), max(h, round(2 * k[1][2]))
        else:
            w, h = max(w, 720), max(h, 576)
        old = sizes.get(view.video, (0, 0))
        sizes[view.video] = (max(old[0], w), max(old[1], h))
    return sizes


def stamp(canvas: np.ndarray, centres, look: dict) -> None:
    """Add one marker profile (coverage 0..1, a Gaussian's 0..1) at each (u, v) of ``centres``
    (the canvas's pixels) into ``canvas`` (h, w) float."""
    h, w = canvas.shape
    gauss = look["profile"] == "gauss"
    radius = int(np.ceil(4 * look["sigma"] if gauss else look["diam"] / 2 + 1))
    for u, v in centres:
        x0, x1 = max(int(u) - radius, 0), min(int(u) + radius + 1, w)
        y0, y1 = max(int(v) - radius, 0), min(int(v) + radius + 1, h)
        if x0 >= x1 or y0 >= y1:
            continue
        xs, ys = np.arange(x0, x1) + 0.5 - u, np.arange(y0, y1) + 0.5 - v
        if gauss:
            value = np.exp(-(ys[:, None] ** 2 + xs[None, :] ** 2) / (2 * look["sigma"] ** 2))
        elif look["profile"] == "hard":
            value = (ys[:, None] ** 2 + xs[None, :] ** 2 <= (look["diam"] / 2) ** 2).astype(float)
        else:
            sub = (np.arange(8) + 0.5) / 8 - 0.5
            sx, sy = (xs[:, None] + sub).ravel(), (ys[:, None] + sub).ravel()
            inside = sy[:, None] ** 2 + sx[None, :] ** 2 <= (look["diam"] / 2) ** 2
            value = inside.reshape(len(ys), 8, len(xs), 8).mean(axis=(1, 3))
        canvas[y0:y1, x0:x1] += value


def render(model: KinematicModel, rig: Rig, variant: str, n: int, seed: int, out: Path) -> list[Path]:
    """Write ``out``/video<k>.avi per video and ``out``/truth.csv; returns the videos."""
    look, rng = VARIANTS[variant], np.random.default_rng(seed)
    q, sizes = postures(model, n, rng), frame_sizes(rig)
    out.mkdir(parents=True, exist_ok=True)
    colour = look.get("codec") == "MJPG"
    fourcc = cv2.VideoWriter_fourcc(*"MJPG") if colour else 0  # 0: raw frames, read back bit-exact
    writers = {k: cv2.VideoWriter(str(out / f"video{k}.avi"), fourcc, 25.0, size, colour)
               for k, size in sorted(sizes.items())}
    bg, peak, blur = look.get("bg", 0), look.get("peak", 255), look.get("blur", 1)
    for t in range(n):
        times = t + np.linspace(-1 / 3, 1 / 3, blur) if blur > 1 else np.array([float(t)])
        proj = rig.project(model.marker_positions(q(times)))  # (S, V, M, 2)
        hidden = ((int(rng.integers(len(rig.views))), int(rng.integers(len(model.markers))))
                  if rng.random() < look.get("occlude", 0.0) else None)
        frames = {k: np.full((h, w), float(bg)) + rng.normal(0, look.get("bg_sigma", 0), (h, w))
                  for k, (w, h) in sizes.items()}
        for v, view in enumerate(rig.views):
            x, y, rw, rh = view.roi if view.roi is not None else (0, 0, *sizes[view.video])
            canvas = np.zeros((rh, rw))
            for s in range(len(times)):
                stamp(canvas, [proj[s, v, m] - (x, y) for m in range(len(model.markers)) if (v, m) != hidden],
                      look)
            canvas /= len(times)
            ghosts = look.get("ghosts", 0)
            stamp(canvas, np.column_stack([rng.uniform(10, rw - 10, ghosts),
                                           rng.uniform(10, rh - 10, ghosts)]), look)
            frames[view.video][y:y + rh, x:x + rw] += (peak - bg) * canvas
        for k, frame in frames.items():
            image = np.clip(np.rint(np.full_like(frame, bg) if t in look.get("blank", ()) else frame), 0, 255)
            image = image.astype(np.uint8)
            writers[k].write(cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if colour else image)
    for writer in writers.values():
        writer.release()
    with open(out / "truth.csv", "w", newline="") as fh:
        rows = csv.writer(fh)
        rows.writerow(["sample", *model.dof_names])
        rows.writerows([t, *q(t)] for t in range(n))
    return [out / f"video{k}.avi" for k in sorted(sizes)]


def fit(videos: list[Path], folder: Path, out: Path, threshold: str | None) -> None:
    """``mocap fit`` with default settings and ``--threshold`` where given, as a lab runs it."""
    command = [sys.executable, "-c", "from cli.app import app; app()", "fit", *map(str, videos),
               "--model", str(folder / "model.xml"), "--rig", str(folder / "rig.json"), "--out", str(out),
               *(["--threshold", threshold] if threshold is not None else [])]
    result = subprocess.run(command, cwd=ROOT, capture_output=True, text=True)
    if result.returncode:
        raise SystemExit(f"mocap fit failed ({result.returncode}): {result.stderr.strip().splitlines()[-1]}")


def evaluate(truth_csv: Path, fitted: Path, model: KinematicModel) -> str:
    """One line of figures: ``fitted``'s angles.csv and report.json against the truth."""
    truth = np.loadtxt(truth_csv, delimiter=",", skiprows=1)[:, 1:]
    with open(fitted / "angles.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    angles = np.array([[float(r[d]) if r[d] else np.nan for d in model.dof_names] for r in rows])
    error = np.abs(angle_errors(model, angles, truth))
    worst = np.where(np.isnan(error).all(axis=1), np.inf, np.nanmax(np.nan_to_num(error, nan=np.inf), axis=1))
    status = np.array([r["status"] for r in rows])
    rmse = np.sqrt(np.nanmean(error ** 2, axis=0))
    report = json.loads((fitted / "report.json").read_text())
    counts = "/".join(str(report["status"][s]) for s in ("ok", "over_threshold", "no_detections"))
    far, ok = worst > FAR_OFF_DEG, status == "ok"
    unflagged = far_off_unflagged(worst, ok, np.array([r["alternative_deg"] != "" for r in rows]))
    return (f"RMSE median {np.nanmedian(rmse):6.3f} worst {np.nanmax(rmse):6.2f}  within 5° "
            f"{100 * np.mean(worst <= 5):5.1f} %  > 10° {np.sum(far):3d} "
            f"(ok {np.sum(far & ok)}, no alternative {len(unflagged)})"
            f"  ok/over/none {counts:9s} ambiguous {report['ambiguous']:3d}  "
            f"diameter {fused_marker_diameter(report['settings']['fit']['fusion_px']):.2f} px")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--subject", choices=(*SUBJECTS, "all"), default="all")
    parser.add_argument("--variant", choices=(*VARIANTS, "all"), default="all")
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--threshold", default=None, help="a grey level, 'otsu' or 'auto' "
                        "(default: mocap fit's)")
    args = parser.parse_args()
    for subject in SUBJECTS if args.subject == "all" else (args.subject,):
        folder = SUBJECTS[subject]
        model, rig = KinematicModel.from_xml(folder / "model.xml"), Rig.from_json(folder / "rig.json")
        for variant in VARIANTS if args.variant == "all" else (args.variant,):
            rendered = OUT / subject / variant
            videos = render(model, rig, variant, args.frames, args.seed, rendered)
            fitted = rendered / f"fit-threshold-{args.threshold or 'default'}"
            fit(videos, folder, fitted, args.threshold)
            print(f"{subject:8s} {variant:15s} {evaluate(rendered / 'truth.csv', fitted, model)}", flush=True)


if __name__ == "__main__":
    main()
