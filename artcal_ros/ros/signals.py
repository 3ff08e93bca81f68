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
    spin = ExecutorSpin(executor)         # the executor spins on its own thread
    spin.wait(stop)                       # returns on the first SIGINT or SIGTERM
    node.stop()                           # the node's own threads: nothing publishes after
    shut_down(node, spin)                 # executor (and its spin thread), node, context
"""

from __future__ import annotations

import contextlib
import faulthandler
import os
import signal
import sys
import threading
import time
from types import FrameType

import rclpy
from rclpy.executors import Executor, ExternalShutdownException
from rclpy.node import Node

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
# Seconds an orderly stop may take before the process leaves anyway. The bounded waits of a
# stop add up to a few seconds; a supervisor (ros2 launch, a test) escalates to SIGKILL
# after ~10 s, and a node killed that way loses its last session save and log lines.
STOP_GRACE_S = 6.0
HARD_LIMIT_EXTRA_S = 2.5  # after the grace time: the GIL-free limit (see StopSignals)


class StopSignals:
    """An event set by SIGINT or SIGTERM (Python-level handlers, main thread only).

    Attributes:
        event: set at the first stop signal (later ones are ignored).
        received: the signal that set it (a number), once it came.
    """

    def __init__(self, grace_s: float | None = STOP_GRACE_S) -> None:
        self.event = threading.Event()
        self.received: list[int] = []
        self.grace_s = grace_s

    @classmethod
    def install(cls, grace_s: float | None = STOP_GRACE_S) -> StopSignals:
        """Replace the SIGINT and SIGTERM handlers of this process with one that sets
        the returned object's event (pass ``SignalHandlerOptions.NO`` to ``rclpy.init``
        so rclpy does not install its own over them). After the first, both are ignored.

        ``grace_s``: once a stop signal came, the process ends at the latest this many
        seconds later (exit status 0, after a warning naming the threads still busy and
        their stacks on stderr), whatever thread is still stuck; if even that cannot run
        (the GIL held by a blocked call), :data:`HARD_LIMIT_EXTRA_S` later with status 1
        and the stacks. None: no limit.
        """
        stop = cls(grace_s)
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
        if self.grace_s is not None:
            # Never joined, on purpose: it ends the process if the stop hangs, and dies
            # with the process when the stop finishes in time.
            threading.Thread(target=_leave_after, args=(self.grace_s,), name="stop-watchdog",
                             daemon=True).start()
            # The last resort, on a C thread of the interpreter that needs no GIL: a call
            # into a library that blocks with the GIL held (a DDS participant that does not
            # come down) stops the Python watchdog too. Stacks on stderr, exit status 1.
            faulthandler.dump_traceback_later(self.grace_s + HARD_LIMIT_EXTRA_S, exit=True)

    def is_set(self) -> bool:
        """True once a stop signal came."""
        return self.event.is_set()


def _leave_after(grace_s: float) -> None:
    """End the process ``grace_s`` seconds from now unless it ended by itself before.

    A daemon thread: it dies with a stop that finishes in time, and it still runs while the
    interpreter waits for non-daemon threads at exit (an executor's pool thread stuck in a
    callback would otherwise hold the process forever).
    """
    time.sleep(grace_s)
    busy = sorted(t.name for t in threading.enumerate()
                  if t.is_alive() and t is not threading.current_thread())
    with contextlib.suppress(Exception):  # a closed stream: leave all the same
        sys.stderr.write(f"[WARN] stopping took longer than {grace_s:g} s; leaving now "
                         f"(threads still running: {', '.join(busy) or 'none'}; their stacks "
                         "follow)\n")
        sys.stderr.flush()
        faulthandler.dump_traceback(sys.stderr, all_threads=True)
    with contextlib.suppress(Exception):  # a closed stream: leave all the same
        sys.stdout.flush()
    os._exit(0)


class ExecutorSpin:
    """Spins an executor on a thread ("spin executor") that it starts and joins.

    Args:
        executor: the executor, with its nodes added.
    """

    def __init__(self, executor: Executor) -> None:
        self.executor = executor
        self._stop_asked = threading.Event()
        self._errors: list[Exception] = []
        self._thread = threading.Thread(target=self._spin, name="spin executor", daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        try:
            self.executor.spin()
        except ExternalShutdownException:
            pass
        except Exception as e:  # after a stop signal: the executor being taken down
            if not self._stop_asked.is_set():
                self._errors.append(e)

    def wait(self, stop: StopSignals, *, poll_s: float = 0.1) -> None:
        """Wait until a stop signal, or until the spin ends by itself.

        The main thread only waits here, so the signal handlers run promptly. Then stop
        the node's own threads and call :func:`shut_down`.

        Raises:
            Exception: whatever the executor raised before any stop signal came.
        """
        while self._thread.is_alive() and not stop.event.wait(poll_s):
            pass
        if stop.is_set():
            self._stop_asked.set()
        if self._errors:
            raise self._errors[0]

    def close(self, timeout_s: float = 2.0) -> bool:
        """Shut the executor down and join the spin thread (up to ``timeout_s`` s each);
        whether the thread ended."""
        self._stop_asked.set()
        self.executor.shutdown(timeout_sec=timeout_s)
        self._thread.join(timeout_s)
        return not self._thread.is_alive()


def shut_down(node: Node, spin: ExecutorSpin, *, timeout_s: float = 2.0) -> None:
    """Take the executor (and its spin thread), the node and the context down, in that
    order, without a word.

    Call it after the node's own threads stopped publishing: nothing may log or publish
    once the context is gone.
    """
    context = node.context
    spin.close(timeout_s)
    node.destroy_node()
    rclpy.try_shutdown(context=context)
