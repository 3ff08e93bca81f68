"""The calibrator node's threads, in process over real rclpy: named for what they do while it
runs, and none left running once its stop() and shut_down() returned, after images were
tracked and measured and a ~/calibrate solved."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import rclpy
from rclpy.context import Context
from rclpy.executors import MultiThreadedExecutor
from sensor_msgs.msg import Image
from std_srvs.srv import Trigger

from artcal_ros.ros.calibrator import CalibratorNode
from artcal_ros.ros.signals import ExecutorSpin, shut_down
from test.integration.frames import CalibrationBag, image_messages
from test.integration.qos import RELIABLE
from test.integration.ros_harness import Probe, wait_until
from test.integration.streaming import Streamer

NAME = "threads_test"
NODE_THREADS = {"track", "measure views", "solve", "save session", "spin executor"}


def test_no_node_thread_outlives_stop(tmp_path: Path, probe: Probe,
                                      bag: CalibrationBag) -> None:
    before = set(threading.enumerate())
    context = Context()
    rclpy.init(args=["--ros-args", "-r", f"__ns:=/{NAME}",
                     "-p", "min_views:=3", "-p", f"camera_name:={NAME}",
                     "-p", f"output_file:={tmp_path / 'camera.yaml'}"], context=context)
    try:
        node = CalibratorNode(node_name=NAME, context=context)
        executor = MultiThreadedExecutor(num_threads=4, context=context)
        executor.add_node(node)
        spin = ExecutorSpin(executor)
        running = {t.name for t in threading.enumerate() if t not in before}
        assert running >= NODE_THREADS, running

        frames = image_messages(bag)
        frames = [frames[i] for i in np.linspace(0, len(frames) - 1, 8).round().astype(int)]
        publisher = probe.node.create_publisher(Image, f"/{NAME}/image", RELIABLE)
        streamer = Streamer(publisher, frames, 0.2)
        try:
            wait_until(lambda: len(node.collector.snapshot().views) >= 3, 180, "3 views")
        finally:
            streamer.stop()
            probe.node.destroy_publisher(publisher)
        # "measure views" did the work (counted once its view is in and handed on)
        wait_until(lambda: node.live.counts().measured >= 3, 30, "3 frames counted measured")
        answer = probe.call(Trigger, f"{node.get_fully_qualified_name()}/calibrate",
                            timeout=300)
        assert answer.success, answer.message  # the "solve" thread did
        assert node.last_summary == answer.message
        assert node.frame_id == frames[0].header.frame_id

        assert node.stop(timeout=10.0) == []
        shut_down(node, spin)
    finally:
        rclpy.try_shutdown(context=context)
    left = sorted(t.name for t in threading.enumerate()
                  if t not in before and t.is_alive() and t.name in NODE_THREADS)
    assert left == [], f"threads outlived the node's stop: {left}"
