"""Is the reported projection uncertainty honest, and does "ready" mean a good camera?

    python -m bench.uncertainty              # 20 sessions per preset (~15 minutes loaded)
    python -m bench.uncertainty --quick      # 6 sessions per preset
    python -m bench.uncertainty --rendered 8 # + 8 rendered, detected webcam sessions

Each session is 40 random views (``synth.random_poses``) of the default board through one
camera preset (webcam and hd plumb_bob k1 k2, wide plumb_bob k1-k3). Detections are the true
corners plus synthetic noise (rendering and detecting 2,400 frames would take hours here):

- ``iid``: Gaussian, 0.03 px per axis, the detector's sigma exact;
- ``realistic``: each view its own noise level (0.015 - 0.06 px, log-uniform: focus,
  compression), larger for small markers (x sqrt(20 px / side), at most 2x); the error of a
  corner is the offsets of the two marker sides that meet there (each side shared by two
  corners), plus a common outward shift of every marker's corners in the view (an edge
  shift left over, 0.3 x the view's level); the sigmas the detector reports are off by a
  factor per view (0.6 - 1.6) and by 20 % per point.

The views are added one by one to the live solve (:class:`LiveSolver`, what the node
runs). Honesty: at 20 views the reported projection uncertainty (1-sigma, RMS over the
image) against the actual projection difference from the true camera; the share of
sessions with the ratio within 0.5x - 2x, for the live solve and for ``calibrate()`` on the
same views. Because one session's error is one draw, even an exact 1-sigma misses that band
sometimes: ``chance`` is the share an exact one would reach on these sessions (errors drawn
from each session's own covariance), ``best possible`` the share the best single figure per
session would reach (an upper bound for any report). Ready means good: the first view count
at which min_views (10) are in and the uncertainty is <= ``readiness.max_uncertainty``, and the
actual projection difference then, against 2x the bound (0.1 px, and a strict 0.03 px).
``--rendered N``: N webcam sessions of 20 rendered views in ``bench.tone``'s realistic
light detected by one ``Detector`` (``bench.calibration_seeds``' sets), honesty only.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.calibrate import calibrate
from artcal_ros.core.calibrate.model import free_columns, free_jacobian
from artcal_ros.core.calibrate.quality import image_grid, projection_difference
from artcal_ros.core.calibrate.solve import SolveOptions, project_jacobian
from artcal_ros.core.detections import Detections
from artcal_ros.core.errors import CalibrationError
from artcal_ros.core.live.live_solve import LiveEstimate, LiveSolveConfig, LiveSolver
from artcal_ros.synth import Camera, random_poses
from artcal_ros.synth.poses import marker_truth

BOARD = Board()
PRESETS = {"webcam": 0, "hd": 0, "wide": 3}  # preset -> radial terms (0: k1 k2)
SESSION_VIEWS = 40
HONESTY_VIEWS = 20
MIN_VIEWS = 10
BOUNDS = (0.1, 0.03)  # readiness.max_uncertainty: the default and a strict one
EDGE_SHIFT = 0.3  # the left-over edge shift of a view, x its noise level


def noisy_view(cam: Camera, rvec: np.ndarray, tvec: np.ndarray, rng: np.random.Generator,
               kind: str, source: str) -> Detections:
    """The true corners of one view plus ``kind`` noise (see the module docstring)."""
    corners, _, inside, side = marker_truth(BOARD, cam, rvec, tvec)
    c = corners[inside]
    n = len(c)
    if kind == "iid":
        noisy = c + rng.normal(0.0, 0.03, c.shape)
        return Detections(BOARD.ids[inside], noisy, noisy.mean(axis=1), cam.size,
                          corner_sigma_px=np.full((n, 4), 0.03), source=source)
    level = float(np.exp(rng.uniform(np.log(0.015), np.log(0.06))))
    sigma = level * np.clip(np.sqrt(20.0 / side[inside]), 0.5, 2.0)  # (n,) per marker
    # Side k runs from corner k to corner k + 1; its offset moves both along its normal.
    d = np.roll(c, -1, axis=1) - c
    normal = np.stack([d[..., 1], -d[..., 0]], axis=2) / np.maximum(
        np.linalg.norm(d, axis=2, keepdims=True), 1e-9)
    offset = rng.normal(0.0, 1.0, (n, 4))[..., None] * sigma[:, None, None] * normal
    err = offset + np.roll(offset, 1, axis=1)  # corner k: sides k - 1 and k
    centre = c.mean(axis=1, keepdims=True)
    out = c - centre
    err += EDGE_SHIFT * level * rng.normal() * out / np.maximum(
        np.linalg.norm(out, axis=2, keepdims=True), 1e-9)
    noisy = c + err
    told = (np.repeat(sigma[:, None], 4, axis=1) * np.exp(rng.uniform(np.log(0.6), np.log(1.6)))
            * np.exp(rng.normal(0.0, 0.2, (n, 4))))
    return Detections(BOARD.ids[inside], noisy, noisy.mean(axis=1), cam.size,
                      corner_sigma_px=told, source=source)


def chance_share(est: LiveEstimate, draws: int,
                 rng: np.random.Generator) -> tuple[float, float]:
    """Shares of errors drawn from the estimate's own covariance whose RMS over the image is
    within 0.5x - 2x of: the reported uncertainty (what an exact 1-sigma reaches), and the
    best single figure any report could give for this session (:func:`best_band_share`)."""
    sol = est.solution
    pix = image_grid(est.image_size, max(est.image_size) / 24.0)
    rays, ok = est.camera.unproject(pix)
    A, _ = project_jacobian(rays[ok], np.zeros(3), np.zeros(3), sol.camera_matrix,
                            sol.dist_coeffs, sol.model)
    A = free_jacobian(A, free_columns(sol.model, sol.free))
    cov = 0.5 * (est.covariance + est.covariance.T)
    delta = rng.multivariate_normal(np.zeros(len(cov)), cov, size=draws)
    shift = delta @ A.T  # (draws, 2N)
    rms = np.sqrt(np.mean(shift[:, 0::2] ** 2 + shift[:, 1::2] ** 2, axis=1))
    ratio = est.uncertainty_rms_px / rms
    return float(np.mean((ratio >= 0.5) & (ratio <= 2.0))), best_band_share(rms)


def best_band_share(rms: np.ndarray) -> float:
    """The largest share of ``rms`` inside one band [c / 2, 2 c], over every c: an upper
    bound on how often any figure reported for the session falls within 0.5x - 2x of its
    actual error, however it is computed, when the error is drawn from that distribution."""
    logs = np.sort(np.log(rms[rms > 0]))
    if not len(logs):
        return float("nan")
    ends = np.searchsorted(logs, logs + np.log(4.0), side="right")
    return float(np.max(ends - np.arange(len(logs))) / len(rms))


def session(preset: str, seed: int, kind: str) -> dict[str, Any]:
    """One growing session: the honesty figures at 20 views and the first ready views."""
    cam = Camera.preset(preset)
    rng = np.random.default_rng(seed)
    poses = random_poses(BOARD, cam, SESSION_VIEWS, rng)
    dets = [noisy_view(cam, r, t, rng, kind, f"{preset}{k}") for k, (r, t) in enumerate(poses)]
    options = SolveOptions(k_coefficients=PRESETS[preset])
    solver = LiveSolver(BOARD, LiveSolveConfig(options=options))
    out: dict[str, Any] = {"seed": seed, "ready": {}, "times": {}}
    for n in range(3, SESSION_VIEWS + 1):
        try:
            est = solver.update(dets[:n], cam.size)
        except CalibrationError:
            continue
        if est is None:
            continue
        true_rms = projection_difference(cam, est.camera)[0]
        if n in (10, 20, 40):
            out["times"][n] = est.seconds
        if n == HONESTY_VIEWS:
            out["live"] = (est.uncertainty_rms_px, true_rms)
            out["chance"], out["best"] = chance_share(est, 400, rng)
            try:
                r = calibrate(dets[:n], BOARD, image_size=cam.size, points="corners",
                              k_coefficients=PRESETS[preset], cross_validation_folds=0)
                out["final"] = (r.projection_uncertainty_px, projection_difference(cam, r)[0])
            except CalibrationError as e:
                out["final_error"] = str(e)
        for bound in BOUNDS:
            if bound not in out["ready"] and n >= MIN_VIEWS and est.uncertainty_rms_px <= bound:
                out["ready"][bound] = (n, est.uncertainty_rms_px, true_rms)
        if len(out["ready"]) == len(BOUNDS) and n >= HONESTY_VIEWS:
            break
    return out


def within(pairs: list[tuple[float, float]]) -> float:
    """Share of (reported, actual) pairs with reported / actual in 0.5 - 2."""
    r = np.array([u / a for u, a in pairs])
    return float(np.mean((r >= 0.5) & (r <= 2.0))) if len(r) else float("nan")


def summarise(preset: str, kind: str, runs: list[dict[str, Any]]) -> dict[str, Any]:
    live = [s["live"] for s in runs if "live" in s]
    final = [s["final"] for s in runs if "final" in s]
    row: dict[str, Any] = {
        "preset": preset, "noise": kind, "sessions": len(runs),
        "live_within": within(live), "final_within": within(final),
        "chance": float(np.mean([s["chance"] for s in runs if "chance" in s])),
        "best": float(np.mean([s["best"] for s in runs if "best" in s])),
        "ratio_median": float(np.median([u / a for u, a in live])),
        "ratio_rms": float(np.sqrt(np.mean([a * a for _, a in live])
                                   / np.mean([u * u for u, _ in live]))),
        "uncertainty_median": float(np.median([u for u, _ in live])),
        "actual_median": float(np.median([a for _, a in live])),
        "times": {n: float(np.median([s["times"][n] for s in runs if n in s["times"]]))
                  for n in (10, 20, 40) if any(n in s["times"] for s in runs)}}
    for bound in BOUNDS:
        hits = [s["ready"][bound] for s in runs if bound in s["ready"]]
        row[f"ready_{bound}"] = {
            "sessions_ready": len(hits),
            "good": float(np.mean([t <= 2 * bound for _, _, t in hits])) if hits else float("nan"),
            "views_median": float(np.median([n for n, _, _ in hits])) if hits else float("nan"),
            "actual_worst": max((t for _, _, t in hits), default=float("nan"))}
    r1, r2 = row[f"ready_{BOUNDS[0]}"], row[f"ready_{BOUNDS[1]}"]
    print(f"{preset:7s} {kind:9s} within 0.5-2x: live {100 * row['live_within']:3.0f} % "
          f"final {100 * row['final_within']:3.0f} % (chance {100 * row['chance']:3.0f} %, "
          f"best possible {100 * row['best']:3.0f} %); "
          f"actual/reported RMS {row['ratio_rms']:.2f}; ready@{BOUNDS[0]}: "
          f"{r1['sessions_ready']}/{len(runs)} at {r1['views_median']:.0f} views, good "
          f"{100 * r1['good']:.0f} %; ready@{BOUNDS[1]}: {r2['sessions_ready']}/{len(runs)} at "
          f"{r2['views_median']:.0f} views, good {100 * r2['good']:.0f} % (worst "
          f"{r2['actual_worst']:.3f} px); update s {row['times']}", flush=True)
    return row


def rendered(n: int, cache: Path) -> dict[str, Any]:
    """Honesty on rendered, detected webcam sessions of 20 views (bench.calibration_seeds)."""
    from bench.calibration_seeds import BOARD_SEEDS, realistic_views

    pairs, final = [], []
    for seed in BOARD_SEEDS[:n]:
        s = realistic_views("webcam", seed, cache)
        est = LiveSolver(BOARD).update(s["dets"], (640, 480))
        cam = Camera.preset("webcam")
        assert est is not None
        pairs.append((est.uncertainty_rms_px, projection_difference(cam, est.camera)[0]))
        r = calibrate(s["dets"], BOARD, image_size=cam.size, cross_validation_folds=0)
        final.append((r.projection_uncertainty_px, projection_difference(cam, r)[0]))
        print(f"  rendered webcam {seed}: reported {pairs[-1][0]:.4f} actual {pairs[-1][1]:.4f}"
              f" (final {final[-1][0]:.4f} / {final[-1][1]:.4f}); reprojection RMS "
              f"{est.reprojection_rms_px:.4f}", flush=True)
    row = {"sessions": n, "live_within": within(pairs), "final_within": within(final),
           "pairs": pairs, "final": final}
    print(f"rendered webcam: within 0.5-2x live {100 * row['live_within']:.0f} % final "
          f"{100 * row['final_within']:.0f} %", flush=True)
    return row


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="6 sessions per preset")
    parser.add_argument("--sessions", type=int, default=20)
    parser.add_argument("--noise", default="realistic,iid", help="noise models to run")
    parser.add_argument("--rendered", type=int, default=0,
                        help="also this many rendered webcam sessions (honesty only)")
    parser.add_argument("--work", default="/tmp/artcal_bench", help="scratch directory")
    args = parser.parse_args(argv)
    warnings.simplefilter("ignore", RuntimeWarning)
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    sessions = 6 if args.quick else args.sessions
    results: dict[str, Any] = {"rows": []}
    t0 = time.monotonic()
    for kind in args.noise.split(","):
        for k, preset in enumerate(PRESETS):
            runs = [session(preset, 8000 + 100 * k + s, kind) for s in range(sessions)]
            results["rows"].append(summarise(preset, kind, runs))
    if args.rendered:
        results["rendered"] = rendered(args.rendered, work / "seeds")
    print(f"({time.monotonic() - t0:.0f} s)")
    (work / "uncertainty.json").write_text(json.dumps(results, indent=2, default=str))
    print(f"results in {work / 'uncertainty.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
