"""Calibration from 20 realistic views over several seeds: mean and worst per preset.

    python -m bench.calibration --seeds 8            # webcam, hd, wide, 8 seeds each
    python -m bench.calibration --seeds 8 --presets webcam --diagnose --per-frame

Each seed renders 20 random views of the default board through ``bench.tone``'s realistic
light (defocus 0.5 - 1.8 px, JPEG 70 - 95, exposure 6 - 150 %; the poses and light drawn
as ``bench.tone`` draws them, so seed 7200 is its webcam set), detects them with one
``Detector`` and calibrates corners and centres (``bench.calibration``'s solve); the figure
is the projection difference RMS against the true camera. Seeds per preset: webcam 7200,
7210, 7220, 7230, 7310, 7320, 7330, 7340, ...; hd one more (7201, ...), wide two more. Rows:
webcam and hd plumb_bob k1 k2; wide the rational model (k1-k6), and wide-k3 the same
detections through plumb_bob k1-k3. ``--per-frame`` detects each view with a fresh
``Detector`` (as ``artcal_ros.detect(image, board)`` does: no tone curve or lens pooled over
the views).
``--diagnose`` adds, per preset, the detected corners' radial error against the truth by
distance from the principal point (positive: outward), calibrations from the true corners
plus 0.03 px noise and plus noise of the detections' own RMS error on the same views (what
the solve does without detection bias), and the corners in the image corners (beyond 90 % of
the half diagonal, where a model with many radial terms is fitted from a few points): their
number, mean radial error, RMS error against the truth and the detector's median sigma.
"""

from __future__ import annotations

import itertools
import pickle
import time
from pathlib import Path
from typing import Any

import numpy as np

from artcal_ros.core.calibrate import calibrate
from artcal_ros.core.calibrate.quality import projection_difference
from artcal_ros.core.detect import Detector
from artcal_ros.core.detections import Detections
from artcal_ros.synth import Camera, random_poses, render_view

BOARD_SEEDS = (7200, 7210, 7220, 7230, 7310, 7320, 7330, 7340, 7350, 7360, 7370, 7380)
# row -> (camera preset, seed offset, model, radial terms: 0 the model's default); wide-k3
# solves the same detections as wide
SEED_PRESETS = {"webcam": ("webcam", 0, "plumb_bob", 0), "hd": ("hd", 1, "plumb_bob", 0),
                "wide": ("wide", 2, "rational_polynomial", 0),
                "wide-k3": ("wide", 2, "plumb_bob", 3),
                "fisheye": ("fisheye", 3, "equidistant", 0)}
RADII = (0.0, 0.25, 0.5, 0.75, 1.0)  # bins of radius / half the image diagonal
RIM = 0.9  # radius / half diagonal beyond which a corner counts as in the image corners


def realistic_views(preset: str, seed: int, cache: Path | None,
                    per_frame: bool = False) -> dict[str, Any]:
    """20 realistic views of one seed: detections and the true corners (cached).
    ``per_frame``: each view detected alone (``artcal_ros.detect``), nothing pooled."""
    from bench.tone import BOARD, realistic

    name = f"{preset}_{seed}{'_alone' if per_frame else ''}.pkl"
    path = cache / name if cache else None
    if path is not None and path.exists():
        out: dict[str, Any] = pickle.loads(path.read_bytes())
        return out
    cam = Camera.preset(preset)
    rng = np.random.default_rng(seed)
    detector = Detector(BOARD)
    out = {"dets": [], "truth": []}
    for r, t in random_poses(BOARD, cam, 20, rng):
        view = render_view(BOARD, cam, r, t, photometry=realistic(rng), rng=rng)
        if per_frame:
            detector = Detector(BOARD)
        out["dets"].append(detector.detect(view.image))
        out["truth"].append((view.corners_px, view.centers_px, view.inside))
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(pickle.dumps(out))
    return out


def solve(dets: list[Detections], row: str, points: str) -> float:
    """Projection difference RMS, px, of one calibration (NaN when it fails)."""
    from artcal_ros.core.errors import CalibrationError
    from bench.tone import BOARD

    preset, _, model, k = SEED_PRESETS[row]
    cam = Camera.preset(preset)
    try:
        r = calibrate(dets, BOARD, image_size=cam.size, model=model, points=points,
                      k_coefficients=k, cross_validation_folds=0)
    except CalibrationError:
        return float("nan")
    return projection_difference(cam, r)[0]


def corner_errors(s: dict[str, Any], cam: Camera) -> dict[str, np.ndarray]:
    """Every detected corner of markers inside the image against the truth: radius / half
    diagonal (``r``), error (``err`` (N, 2) px), its radial part (``radial``, + outward) and
    the detector's sigma (``sigma`` px)."""
    from bench.tone import BOARD

    half_diag = 0.5 * float(np.hypot(*cam.size))
    pp = cam.K[[0, 1], [2, 2]]
    rad, err, radial, sigma = [], [], [], []
    for det, (corners, _, inside) in zip(s["dets"], s["truth"], strict=True):
        k = det.ids - BOARD.first_id
        ok = inside[k]
        truth = corners[k[ok]].reshape(-1, 2)
        found = det.corners_px[ok].reshape(-1, 2)
        d = truth - pp
        r = np.linalg.norm(d, axis=1)
        u = d / np.maximum(r, 1e-9)[:, None]
        rad.append(r / half_diag)
        err.append(found - truth)
        radial.append(np.sum((found - truth) * u, axis=1))
        sigma.append(np.asarray(det.corner_sigma_px, float)[ok].reshape(-1))
    return {"r": np.concatenate(rad), "err": np.concatenate(err),
            "radial": np.concatenate(radial), "sigma": np.concatenate(sigma)}


def rim_errors(e: dict[str, np.ndarray]) -> tuple[int, float, float, float]:
    """The corners beyond :data:`RIM`: (count, mean radial error, RMS error, median sigma),
    pixels (NaN where there are none)."""
    sel = (e["r"] >= RIM) & np.all(np.isfinite(e["err"]), axis=1)
    if not sel.any():
        return 0, float("nan"), float("nan"), float("nan")
    return (int(sel.sum()), float(np.mean(e["radial"][sel])),
            float(np.sqrt(np.mean(np.sum(e["err"][sel] ** 2, axis=1)))),
            float(np.nanmedian(e["sigma"][sel])))


def radial_bias(s: dict[str, Any], cam: Camera) -> list[tuple[float, float, int]]:
    """Mean radial error of the detected corners (px, + outward) per radius bin."""
    e = corner_errors(s, cam)
    r_all, e_all = e["r"], e["radial"]
    out = []
    for lo, hi in itertools.pairwise(RADII):
        sel = (r_all >= lo) & (r_all < hi) & np.isfinite(e_all)
        out.append((lo, float(np.mean(e_all[sel])) if sel.any() else float("nan"),
                    int(sel.sum())))
    return out


def true_plus_noise(s: dict[str, Any], seed: int, sigma: float = 0.03) -> list[Detections]:
    """The same views' true corners (the markers detected) plus Gaussian noise."""
    from bench.tone import BOARD

    rng = np.random.default_rng(seed)
    out = []
    for det, (corners, _, inside) in zip(s["dets"], s["truth"], strict=True):
        k = det.ids - BOARD.first_id
        ok = inside[k]
        c = corners[k[ok]] + rng.normal(0.0, sigma, corners[k[ok]].shape)
        out.append(Detections(det.ids[ok], c, c.mean(axis=1), det.image_size))
    return out


def seeds_table(n_seeds: int, presets: list[str], diagnose: bool, cache: Path | None,
                per_frame: bool = False) -> dict[str, Any]:
    """Per preset: corners and centres over ``n_seeds`` seeds (mean, worst, each seed)."""
    results: dict[str, Any] = {}
    how = "each view detected alone" if per_frame else "one Detector per seed"
    print(f"20 realistic views, {n_seeds} seeds, {how}: projection difference RMS px, "
          "mean / worst (each seed)", flush=True)
    for name in presets:
        preset, offset, model, k = SEED_PRESETS[name]
        cam = Camera.preset(preset)
        row: dict[str, Any] = {"model": model, "seeds": [], "corners": [], "centers": [],
                               "true_noise": [], "true_own": [], "bias": [], "rim": []}
        t0 = time.monotonic()
        for seed in (s + offset for s in BOARD_SEEDS[:n_seeds]):
            s = realistic_views(preset, seed, cache, per_frame)
            row["seeds"].append(seed)
            row["corners"].append(solve(s["dets"], name, "corners"))
            row["centers"].append(solve(s["dets"], name, "centers"))
            line = (f"  {name} {seed}: corners {row['corners'][-1]:.4f} "
                    f"centres {row['centers'][-1]:.4f}")
            if diagnose:
                e = corner_errors(s, cam)
                own = float(np.sqrt(np.nanmean(e["err"] ** 2)))  # per axis
                row["true_noise"].append(solve(true_plus_noise(s, seed), name, "corners"))
                row["true_own"].append(solve(true_plus_noise(s, seed, own), name, "corners"))
                row["bias"].append(radial_bias(s, cam))
                row["rim"].append(rim_errors(e))
                n, rb, rms, sig = row["rim"][-1]
                line += (f"  true+0.03 {row['true_noise'][-1]:.4f}  true+{own:.3f} "
                         f"{row['true_own'][-1]:.4f}  radial bias "
                         + " ".join(f"{b:+.4f}" for _, b, _ in row["bias"][-1])
                         + f"  rim: {n} corners, radial {rb:+.3f} RMS {rms:.3f} "
                         f"sigma {sig:.3f}")
            print(line, flush=True)
        for key in ("corners", "centers", "true_noise", "true_own"):
            v = np.array(row[key], float)
            if len(v):
                row[key + "_mean"], row[key + "_worst"] = float(np.nanmean(v)), float(np.nanmax(v))
        model += f" k1-k{k}" if k else ""
        print(f"{name:7s} {model:20s} corners {row['corners_mean']:.4f} / "
              f"{row['corners_worst']:.4f}  centres {row['centers_mean']:.4f} / "
              f"{row['centers_worst']:.4f}  ({time.monotonic() - t0:.0f} s)", flush=True)
        if diagnose:
            b = np.nanmean([[x[1] for x in bb] for bb in row["bias"]], axis=0)
            print(f"        true corners + 0.03 px: {row['true_noise_mean']:.4f} / "
                  f"{row['true_noise_worst']:.4f}; radial bias by r/half-diagonal "
                  + " ".join(f"[{lo:.2f}] {x:+.4f}"
                             for lo, x in zip(RADII, b, strict=False)), flush=True)
            rim = np.array(row["rim"], float)
            n = rim[:, 0]
            print(f"        true corners + their own RMS error: {row['true_own_mean']:.4f} / "
                  f"{row['true_own_worst']:.4f}; beyond {RIM:.0%} of the half diagonal "
                  f"{int(n.sum())} corners, radial {np.nansum(n * rim[:, 1]) / n.sum():+.3f} "
                  f"RMS {np.sqrt(np.nansum(n * rim[:, 2] ** 2) / n.sum()):.3f} px, "
                  f"median sigma {np.nanmedian(rim[:, 3]):.3f}", flush=True)
        results[name] = row
    return results
