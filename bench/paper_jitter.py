"""Jitter against marker size: one pose rendered again and again with fresh sensor noise.

Run by :mod:`bench.paper`. The paper measured ARTag's corner jitter at about 0.03 px (a
640 x 480 camera, good light and focus), "the same regardless of marker size". Here: the
``webcam`` preset (640 x 480), a 3 x 3 marker grid (30 mm markers, 10 mm gaps) at the image
centre, turned 10 degrees, at the distance where a marker's side is the wanted size in
pixels. The renderer's clean light with the light gradient off and one fixed background, so
that only the sensor noise changes between renders. Per size: the standard deviation of
every corner (and centre) coordinate over the renders, RMS over the points; the bias is
the RMS distance of the points' mean from their true image.
"""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np

from artcal_ros import Board, detect
from artcal_ros.synth import Backdrop, Camera, Photometry, render_view

BOARD = Board(cols=3, rows=3, marker_length=0.03, marker_separation=0.01)
LIGHT = Photometry.clean().with_(gradient=0.0)
METHODS = ("ours corners", "ours centres", "OpenCV subpix corners")


def _opencv() -> Any:
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    return cv2.aruco.ArucoDetector(BOARD.dictionary, params)


def jitter_size(side_px: float, renders: int, seed: int) -> dict[str, Any]:
    """{"size px": measured median side, "<method> std": px, "<method> bias": px} for
    markers of about ``side_px`` pixels."""
    cam = Camera.preset("webcam")
    x0, y0, x1, y1 = BOARD.extent_m
    centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])
    rvec = np.array([math.radians(10.0), math.radians(4.0), math.radians(3.0)])
    R = cv2.Rodrigues(rvec)[0]
    dist = cam.K[0, 0] * BOARD.marker_length / side_px
    tvec = np.array([0.0, 0.0, dist]) - R @ centre
    rng = np.random.default_rng(seed)
    backdrop = Backdrop.random(BOARD, np.random.default_rng(seed))
    cv_detector = _opencv()
    stacks: dict[str, dict[int, list[np.ndarray]]] = {m: {} for m in METHODS}
    view = None
    for _ in range(renders):
        view = render_view(BOARD, cam, rvec, tvec, photometry=LIGHT, rng=rng, backdrop=backdrop)
        det = detect(view.image, BOARD)
        for i, c, m in zip(det.ids, det.corners_px, det.centers_px, strict=True):
            stacks["ours corners"].setdefault(int(i), []).append(c)
            stacks["ours centres"].setdefault(int(i), []).append(m)
        quads, ids, _ = cv_detector.detectMarkers(view.image)
        for i, q in zip(np.zeros(0) if ids is None else ids.ravel(), quads, strict=True):
            stacks["OpenCV subpix corners"].setdefault(int(i), []).append(q.reshape(4, 2))
    assert view is not None
    out: dict[str, Any] = {"size px": float(np.median(view.side_px[view.inside]))}
    for name, per_id in stacks.items():
        stds, bias = [], []
        for i, v in per_id.items():
            if len(v) < renders:
                continue  # a marker missed in some renders: its spread is not comparable
            a = np.stack(v)
            true = view.centers_px[i] if name == "ours centres" else view.corners_px[i]
            stds.append(np.std(a, axis=0).ravel())
            bias.append(np.linalg.norm(a.mean(axis=0).reshape(-1, 2) - true.reshape(-1, 2),
                                       axis=1))
        out[f"{name} std"] = (float(np.sqrt(np.mean(np.square(np.concatenate(stds)))))
                              if stds else math.nan)
        out[f"{name} bias"] = (float(np.sqrt(np.mean(np.square(np.concatenate(bias)))))
                               if bias else math.nan)
    return out
