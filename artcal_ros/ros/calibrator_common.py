"""What the single-camera and the rig calibrator nodes share: output QoS, the ``~/calibrate``
answer, and the spin from start to the process's exit."""

from __future__ import annotations

import gc
import os
import sys
import threading
from collections.abc import Callable

from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_srvs.srv import Trigger

from artcal_ros.ros.signals import ExecutorSpin, StopSignals, shut_down

__all__ = ["LATCHED_QOS", "OVERLAY_QOS", "answer_calibrate", "spin_until_stopped"]

LATCHED_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
OVERLAY_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                         reliability=ReliabilityPolicy.RELIABLE)


def answer_calibrate(node: Node, solving: threading.Lock, stopping: threading.Event,
                     calibrate: Callable[[], tuple[bool, str]],
                     response: Trigger.Response) -> Trigger.Response:
    """Fill ``response`` of ``~/calibrate``: ``calibrate()`` (success, message), one at a time.

    A call while ``solving`` is held is refused at once; an exception from ``calibrate`` is
    logged and answered as an internal error, so a bug does not take the node down. The
    answer is logged unless the node is ``stopping``.
    """
    if not solving.acquire(blocking=False):
        response.success = False
        response.message = "a calibration is already running; try again when it ends"
        return response
    try:
        response.success, response.message = calibrate()
    except Exception as e:  # a bug must not take the node down with it
        node.get_logger().error(f"~/calibrate failed: {e!r}")
        response.success, response.message = False, f"internal error: {e!r}"
    finally:
        solving.release()
    if stopping.is_set() or not node.context.ok():
        return response  # shutting down: rosout may be gone, nobody reads the log
    # rclpy refuses two severities from one call site, hence two calls.
    if response.success:
        node.get_logger().info(f"~/calibrate: {response.message}")
    else:
        node.get_logger().warning(f"~/calibrate: {response.message}")
    return response


def spin_until_stopped(node: Node, stop_node: Callable[[float], list[str]], num_threads: int,
                       signals: StopSignals) -> int:
    """Spin ``node`` on ``num_threads`` executor threads until a stop signal, stop it and
    shut down; the exit status (0).

    ``stop_node(timeout)``: the node's stop, which returns the names of its threads still
    running. What start-up made (modules, the node, detector tables) is frozen out of the
    garbage collector's sight first: a full collection no longer walks it between two frames.
    """
    gc.collect()
    gc.freeze()
    executor = MultiThreadedExecutor(num_threads=num_threads)
    executor.add_node(node)
    spin = ExecutorSpin(executor)
    try:
        spin.wait(signals)
    finally:
        stop_node(1.0)
        shut_down(node, spin)
    # A daemon thread still inside OpenCV when the interpreter finalizes can abort the
    # process ("exception not rethrown"); leaving with os._exit skips that finalization.
    if stop_node(2.0):
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(0)
    return 0
