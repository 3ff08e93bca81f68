"""A stop signal ends the process in bounded time, even with a thread that never returns.

The process runs as a child: it installs the stop handlers, starts a thread, signals itself
and returns from its main code. A non-daemon thread stuck in a call would keep the
interpreter waiting at exit forever; the watchdog ends the process after its grace time,
with status 0 and the stuck thread's name and stack on stderr.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
import time

CHILD = textwrap.dedent("""
    import os, signal, sys, threading
    from artcal_ros.ros.signals import StopSignals

    stop = StopSignals.install(grace_s=1.0)
    release = threading.Event()

    def stuck_in_a_callback():
        release.wait()  # never set when the thread is to hang

    threading.Thread(target=stuck_in_a_callback, name="stuck", daemon=False).start()
    os.kill(os.getpid(), signal.SIGINT)
    os.kill(os.getpid(), signal.SIGINT)  # a second one, as ros2 launch forwards it
    assert stop.event.wait(5.0), "the stop event was not set"
    if sys.argv[1] == "clean":
        release.set()
    print("main done", flush=True)
""")


def run_child(mode: str) -> tuple[subprocess.CompletedProcess[str], float]:
    t0 = time.monotonic()
    done = subprocess.run([sys.executable, "-c", CHILD, mode], capture_output=True, text=True,
                          timeout=60)
    return done, time.monotonic() - t0


def test_a_stuck_thread_cannot_hold_the_process_after_a_stop_signal() -> None:
    done, took = run_child("stuck")
    assert done.returncode == 0, done.stderr
    assert "main done" in done.stdout
    assert "stopping took longer than 1 s" in done.stderr
    assert "stuck" in done.stderr and "stuck_in_a_callback" in done.stderr, done.stderr
    assert "Traceback" not in done.stderr and "KeyboardInterrupt" not in done.stderr
    assert took < 30, f"the watchdog left after {took:.1f} s"


def test_a_clean_stop_leaves_without_the_watchdog() -> None:
    done, _ = run_child("clean")
    assert done.returncode == 0, done.stderr
    assert "main done" in done.stdout
    assert "stopping took longer" not in done.stderr
    assert "Traceback" not in done.stderr, done.stderr


HOLDS_THE_GIL = textwrap.dedent("""
    import ctypes, os, signal, sys
    from artcal_ros.ros.signals import StopSignals

    stop = StopSignals.install(grace_s=0.5)
    os.kill(os.getpid(), signal.SIGINT)
    assert stop.event.wait(5.0)
    print("blocking with the GIL held", flush=True)
    # A C call that never returns and keeps the GIL (ctypes.PyDLL does not release it),
    # like a library teardown that hangs: the Python watchdog cannot run.
    ctypes.PyDLL(None).pause()
""")


def test_a_call_that_blocks_holding_the_gil_still_ends_the_process() -> None:
    t0 = time.monotonic()
    done = subprocess.run([sys.executable, "-c", HOLDS_THE_GIL], capture_output=True,
                          text=True, timeout=60)
    took = time.monotonic() - t0
    assert "blocking with the GIL held" in done.stdout
    assert done.returncode == 1, (done.returncode, done.stderr)
    assert "Timeout" in done.stderr and "most recent call first" in done.stderr, done.stderr
    assert "stopping took longer" not in done.stderr  # the Python watchdog could not run
    assert took < 30, f"left after {took:.1f} s"
