"""The README's picture of the live overlay with the next-pose outline.

    python -m bench.readme_images          # writes docs/img/overlay_next_pose.jpg

Six rendered webcam views of the default board are collected and solved as the node's live
solve does; the seventh frame is drawn as the node's ~/overlay, with the outline of where
the board should be held next (orange), and beside it a frame rendered at that pose, where
the live board matches the outline (green).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detect import Detector
from artcal_ros.core.live.coverage import CoverageConfig, ViewCollector
from artcal_ros.core.live.guidance import next_pose, pose_match
from artcal_ros.core.live.live_solve import LiveSolver
from artcal_ros.core.live.overlay import draw_next_pose, render_overlay
from artcal_ros.core.live.readiness import live_readiness
from artcal_ros.synth import Camera, Photometry, random_poses, render_view

MAX_UNCERTAINTY_PX = 0.1  # readiness.max_uncertainty's default
OUT = Path(__file__).resolve().parents[1] / "docs" / "img" / "overlay_next_pose.jpg"


def overlay_pictures(seed: int = 11, width: int = 640) -> np.ndarray:
    """The two overlays side by side (BGR): the outline to reach, then reached."""
    board, cam = Board(), Camera.preset("webcam")
    rng = np.random.default_rng(seed)
    detector = Detector(board)
    collector = ViewCollector(board, CoverageConfig())
    poses = random_poses(board, cam, 7, rng)
    frames = []
    for rvec, tvec in poses:
        view = render_view(board, cam, rvec, tvec, photometry=Photometry(), rng=rng)
        frames.append((view.image, detector.detect(view.image)))
    for _, dets in frames[:6]:
        collector.add(dets)
    snap = collector.snapshot()
    assert snap.image_size is not None
    estimate = LiveSolver(board).update(snap.views, snap.image_size)
    if estimate is None:
        raise RuntimeError("the live solve made no estimate from six views")
    suggestion = next_pose(estimate.views, estimate.solution, board, snap.image_size,
                           weighted=estimate.weighted)
    if suggestion is None:
        raise RuntimeError("no next pose")
    there = render_view(board, cam, suggestion.rvec, suggestion.tvec, photometry=Photometry(),
                        rng=rng)
    shown = []
    for image, dets in (frames[6], (there.image, detector.detect(there.image))):
        readiness = live_readiness(snap.readiness, estimate, MAX_UNCERTAINTY_PX)
        overlay = render_overlay(image, dets, snap.counts, readiness, max_width=width)
        match = pose_match(suggestion, dets.corners_px) if len(dets) else 0.0
        draw_next_pose(overlay, suggestion, zoom=overlay.shape[1] / image.shape[1],
                       match=match)
        cv2.putText(overlay, f"next pose: {suggestion.text} (match {match:.2f})",
                    (8, overlay.shape[0] - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 3,
                    cv2.LINE_AA)
        cv2.putText(overlay, f"next pose: {suggestion.text} (match {match:.2f})",
                    (8, overlay.shape[0] - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                    (255, 255, 255), 1, cv2.LINE_AA)
        shown.append(overlay)
    gap = np.full((shown[0].shape[0], 8, 3), 255, np.uint8)
    return np.hstack([shown[0], gap, shown[1]])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.readme_images", description=__doc__)
    parser.add_argument("--out", default=str(OUT), help="the JPEG to write")
    parser.add_argument("--seed", type=int, default=11, help="the rendered session's seed")
    args = parser.parse_args(argv)
    picture = overlay_pictures(args.seed)
    cv2.imwrite(args.out, picture, [cv2.IMWRITE_JPEG_QUALITY, 88])
    print(f"wrote {args.out} ({picture.shape[1]}x{picture.shape[0]})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
