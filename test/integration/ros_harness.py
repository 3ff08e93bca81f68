"""Helpers for tests over real rclpy and DDS: an isolated domain, node processes, a probe node.

Every wait polls a condition with a generous timeout (discovery takes 0.2-3.5 s here);
a timeout only costs time when a test is failing anyway.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import tempfile
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from artcal_ros.ros import processes

ROOT = Path(__file__).resolve().parents[2]
BIN = ROOT / ".venv" / "bin"


def configure_ros_env() -> None:
    """Put this test session on its own DDS domain, on this machine only.

    Called at conftest import, before any rclpy context exists; subprocesses inherit it,
    and a temporary HOME (``ARTCAL_TEST_HOME``, made once) for what nodes save there.
    ARTCAL_TEST_DOMAIN, when set, chooses the domain (so several pytest processes can share
    one); otherwise a random one is drawn and recorded there.
    """
    if "ARTCAL_TEST_DOMAIN" not in os.environ:
        os.environ["ARTCAL_TEST_DOMAIN"] = str(processes.random_domain_id())
    os.environ.update(processes.private_domain_env(int(os.environ["ARTCAL_TEST_DOMAIN"])))
    # The nodes save sessions and logs under $HOME/.ros: a home of the test session's own
    # keeps them out of the user's and apart from other test sessions.
    if "ARTCAL_TEST_HOME" not in os.environ:
        os.environ["ARTCAL_TEST_HOME"] = tempfile.mkdtemp(prefix="artcal_test_home_")
    os.environ["HOME"] = os.environ["ARTCAL_TEST_HOME"]


def stop_all() -> None:
    """Stop every node process still running (after a failed test)."""
    while RUNNING:
        node = RUNNING.pop()
        if node.running():
            # If it needs SIGKILL, the test already failed for a reason of its own.
            with contextlib.suppress(AssertionError):
                node.stop()


def wait_until(predicate: Callable[[], Any], timeout: float, what: str,
               period: float = 0.05) -> Any:
    """Poll ``predicate`` until it returns something truthy; AssertionError naming ``what``."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")
        time.sleep(period)


RUNNING: list[NodeProcess] = []  # stopped after each test by the conftest, pass or fail
STARTED: list[NodeProcess] = []  # this test's nodes, their output checked by the conftest


def crashed_nodes() -> list[str]:
    """The nodes started in this test whose output holds a Python traceback (the list is
    emptied): a node may refuse bad input, but never with a traceback."""
    found = [f"{n.name}:\n{n.output()[-3000:]}" for n in STARTED if "Traceback" in n.output()]
    STARTED.clear()
    return found


class NodeProcess(processes.NodeProcess):
    """One of our console scripts (``.venv/bin/<script> --ros-args ...``), run by the package's
    process runner (:class:`artcal_ros.ros.processes.NodeProcess`: own process group, output
    in ``log_dir/<name>.log``), with test failures as AssertionError."""

    def __init__(self, script: str, ros_args: Sequence[str], log_dir: Path,
                 name: str | None = None, *, per_test: bool = True,
                 env: Mapping[str, str] | None = None) -> None:
        """``env``: the environment to run in (default: this process's)."""
        super().__init__([str(BIN / script), "--ros-args", *ros_args],
                         log_dir / f"{name or script}.log", name=name or script, cwd=ROOT,
                         env=env)
        if per_test:  # else the fixture that started it stops it
            RUNNING.append(self)
            STARTED.append(self)

    def wait(self, timeout: float) -> int:
        """Wait for the process to end by itself; its exit status (AssertionError, with the
        end of its output, if it is still running after ``timeout`` s: it is stopped)."""
        try:
            return super().wait(timeout)
        except subprocess.TimeoutExpired:
            text = self.output()[-2000:]
            self.stop()
            raise AssertionError(f"{self.name} still running after {timeout:g} s:\n"
                                 f"{text}") from None

    def stop(self, timeout: float = 10.0) -> int:
        """SIGINT, then SIGKILL after ``timeout``; the exit status (AssertionError if it
        needed SIGKILL: a node must stop on SIGINT)."""
        killed_before = self.killed  # a second stop() of a killed node just gives its status
        status = super().stop(timeout)
        if self.killed and not killed_before:
            raise AssertionError(f"{self.name} ignored SIGINT for {timeout:g} s; its output "
                                 f"ended:\n{self.output()[-4000:]}")
        return status


PARAMS = ROOT / "config" / "calibrator.yaml"


def calibrator_node(log_dir: Path, name: str, *params: str, image_topic: str | None = None,
                    env: Mapping[str, str] | None = None) -> NodeProcess:
    """The calibrator console script as node ``name`` with config/calibrator.yaml, its
    ``image`` on ``image_topic`` (default ``/<name>/image``), its calibration file in
    ``log_dir``, and ``params`` (``key:=value``) on top."""
    args = ["--params-file", str(PARAMS), "-r", f"__node:={name}",
            "-r", f"image:={image_topic or f'/{name}/image'}",
            "-p", f"output_file:={log_dir / (name + '.yaml')}"]
    for p in params:
        args += ["-p", p]
    return NodeProcess("calibrator", args, log_dir, name=name, env=env)


class Probe:
    """An rclpy node spun on a background thread, with its own context.

    Use :meth:`collect` to record a topic and :meth:`call` for a Trigger-like service.
    """

    def __init__(self, name: str = "artcal_test_probe") -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor

        self.context = Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._lock = threading.Lock()
        self.spin_errors: list[str] = []  # what a callback or a wait raised (spinning goes on)
        self._thread = threading.Thread(target=self._spin, daemon=True, name="probe spin")
        self._thread.start()

    def _spin(self) -> None:
        from rclpy.executors import ExternalShutdownException

        # One error (a service's callback raising, an entity destroyed by a test's thread while
        # the executor waited on it) must not end the spinning that every later test relies on.
        while self.context.ok():
            try:
                self.executor.spin_once(timeout_sec=0.05)
            except ExternalShutdownException:
                return
            except Exception as e:
                if not self.context.ok():
                    return
                if len(self.spin_errors) < 20:
                    self.spin_errors.append(f"{type(e).__name__}: {e}")
                time.sleep(0.05)

    def collect(self, msg_type: type, topic: str, qos: Any) -> list[Any]:
        """Subscribe and append every message to the returned list (thread-safe appends)."""
        box: list[Any] = []
        self.node.create_subscription(msg_type, topic, box.append, qos)
        return box

    def call(self, srv_type: type, name: str, request: Any = None,
             timeout: float = 60.0) -> Any:
        """Call a service once it is available; the response (AssertionError on timeout)."""
        client = self.node.create_client(srv_type, name)
        try:
            if not client.wait_for_service(timeout_sec=20.0):
                raise AssertionError(f"service {name} did not appear within 20 s")
            future = client.call_async(request if request is not None else srv_type.Request())
            wait_until(future.done, timeout, f"an answer from {name}")
            return future.result()
        finally:
            self.node.destroy_client(client)

    def close(self) -> None:
        import rclpy

        rclpy.try_shutdown(context=self.context)
        self._thread.join(2.0)
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()


def diagnostics_values(msgs: list[Any], node_name: str = "calibrator") -> dict[str, str]:
    """The key/values of the newest DiagnosticStatus of ``node_name`` in ``msgs`` ({} if none)."""
    for array in reversed(list(msgs)):
        for status in array.status:
            if status.name.startswith(f"{node_name}:"):
                return {kv.key: kv.value for kv in status.values}
    return {}
