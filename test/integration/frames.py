"""Calibration frames with known truth for the node tests: bags/sample, or rendered if absent."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from test.integration.ros_harness import ROOT

SAMPLE_BAG = ROOT / "bags" / "sample"
IMAGE_TYPE = "sensor_msgs/msg/Image"


@dataclass(frozen=True)
class CalibrationBag:
    """A bag of board images and the camera that took them.

    Attributes:
        path: rosbag2 directory.
        topic: the sensor_msgs/Image topic in it.
        camera: the true camera (K, dist, model, size), a synth Camera.
        frames: count of images; duration_s: recorded span, seconds.
    """

    path: Path
    topic: str
    camera: Any
    frames: int
    duration_s: float


def _render_bag(out: Path, n: int = 14, seed: int = 7) -> None:
    """A stand-in for bags/sample: ``n`` clean webcam views at 2 Hz with truth.json."""
    import numpy as np

    from artcal_ros.bag import BagWriter
    from artcal_ros.core.board import Board
    from artcal_ros.core.images import numpy_to_image
    from artcal_ros.synth import Camera, Photometry, random_poses, render_view
    from artcal_ros.synth.truth import frame_record, write_truth

    board = Board()
    cam = Camera.preset("webcam")
    rng = np.random.default_rng(seed)
    records = []
    with BagWriter(out, storage="directory") as w:
        for k, (rvec, tvec) in enumerate(random_poses(board, cam, n, rng)):
            view = render_view(board, cam, rvec, tvec, photometry=Photometry.clean(), rng=rng)
            stamp = 1_700_000_000_000_000_000 + k * 500_000_000
            w.write("/camera/image_raw", IMAGE_TYPE, stamp,
                    numpy_to_image(view.image, encoding="mono8", stamp_ns=stamp,
                                   frame_id="camera_optical"))
            records.append(frame_record(rvec=rvec, tvec=tvec, ids=view.ids,
                                        corners_px=view.corners_px,
                                        centers_px=view.centers_px, inside=view.inside,
                                        side_px=view.side_px, stamp_ns=stamp))
    write_truth(out / "truth.json", cam, board, records, seed=seed)


def calibration_bag(scratch: Path) -> CalibrationBag:
    """bags/sample if it has a truth.json, else a bag rendered into ``scratch``."""
    from artcal_ros.bag import BagReader
    from artcal_ros.synth.truth import load_truth

    path = SAMPLE_BAG
    if not (path / "truth.json").is_file():
        path = scratch / "rendered_bag"
        if not (path / "truth.json").is_file():
            _render_bag(path)
    with BagReader(path) as r:
        topic = next(t for t, kind in sorted(r.topics.items()) if kind == IMAGE_TYPE)
        stamps = [m.log_time_ns for m in r.messages([topic])]
    return CalibrationBag(path, topic, load_truth(path / "truth.json").camera, len(stamps),
                          (stamps[-1] - stamps[0]) * 1e-9)


def image_messages(bag: CalibrationBag) -> list[Any]:
    """Every image of the bag as a sensor_msgs.msg.Image."""
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import Image

    from artcal_ros.bag import BagReader

    with BagReader(bag.path) as r:
        return [deserialize_message(m.data, Image) for m in r.messages([bag.topic])]
