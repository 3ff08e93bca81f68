"""SIGINT and SIGTERM as one stop request, however many arrive and whenever.

rclpy's own handlers shut the context down from the signal, asynchronously: a worker
thread still inside a frame then meets a publisher whose context is gone (``RCLError``),
a log line finds rosout destroyed, and a second SIGINT (``ros2 launch`` forwards the
terminal's Ctrl-C, so two arrive 50 ms apart) raises ``KeyboardInterrupt`` inside
``executor.shutdown()``'s thread joins. Here a signal only sets an event; the main thread
then stops the node in order (the node's own threads first, then the executor, the node,
the context), and later signals change nothing.

::

    stop = StopSignals.install()          # before rclpy.init
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    ...
    spin = spin_until_stopped(executor, stop)   # returns on the first SIGINT or SIGTERM
    node.stop()                           # the node's own threads: nothing publishes after
    shut_down(node, executor, spin)       # executor, node, context
"""

from __future__ import annotations

import signal
import threading
from types import FrameType

import rclpy
from rclpy.executors import Executor, ExternalShutdownException
from rclpy.node import Node

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class StopSignals:
    """An event set by SIGINT or SIGTERM (Python-level handlers, main thread only).

    Attributes:
        event: set at the first stop signal (later ones are ignored).
        received: the signal that set it (a number), once it came.
    """

    def __init__(self) -> None:
        self.event = threading.Event()
        self.received: list[int] = []

    @classmethod
    def install(cls) -> StopSignals:
        """Replace the SIGINT and SIGTERM handlers of this process with one that sets
        the returned object's event (pass ``SignalHandlerOptions.NO`` to ``rclpy.init``
        so rclpy does not install its own over them). After the first, both are ignored."""
        stop = cls()
        for sig in STOP_SIGNALS:
            signal.signal(sig, stop._on_signal)
        return stop

    def _on_signal(self, signum: int, _frame: FrameType | None) -> None:
        self.received.append(signum)
        self.event.set()
        # Later signals have nothing left to ask. Ignored, they cannot reach the default
        # action either: the interpreter restores that for handlers of its own while it
        # finalizes, and a signal then would end the process with -SIGINT after a clean stop.
        for sig in STOP_SIGNALS:
            signal.signal(sig, signal.SIG_IGN)

    def is_set(self) -> bool:
        """True once a stop signal came."""
        return self.event.is_set()


def spin_until_stopped(executor: Executor, stop: StopSignals, *,
                       poll_s: float = 0.1) -> threading.Thread:
    """Spin ``executor`` on a daemon thread until a stop signal, or until it ends by itself.

    The main thread only waits, so the signal handlers run promptly. The caller then
    stops its node and calls :func:`shut_down`.

    Returns:
        the spin thread (still running: :func:`shut_down` ends it).

    Raises:
        Exception: whatever the executor raised before any stop signal came.
    """
    errors: list[Exception] = []

    def spin() -> None:
        try:
            executor.spin()
        except ExternalShutdownException:
            pass
        except Exception as e:  # after a stop signal: the executor being taken down
            if not stop.is_set():
                errors.append(e)

    thread = threading.Thread(target=spin, name="spin", daemon=True)
    thread.start()
    while thread.is_alive() and not stop.event.wait(poll_s):
        pass
    if errors:
        raise errors[0]
    return thread


def shut_down(node: Node, executor: Executor, spin_thread: threading.Thread | None, *,
              timeout_s: float = 2.0) -> None:
    """Take the executor, the node and the context down, in that order, without a word.

    Call it after the node's own threads stopped publishing: nothing may log or publish
    once the context is gone.
    """
    executor.shutdown(timeout_sec=timeout_s)
    if spin_thread is not None:
        spin_thread.join(timeout_s)
    node.destroy_node()
    rclpy.try_shutdown()
