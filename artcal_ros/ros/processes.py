"""Node processes for the demo and the integration tests, and the private DDS domain they share.

One runner for both (the demo and ``test/integration/ros_harness.py``): each node runs in its
own process group (so a stop reaches whatever it started too), stdout and stderr go to one log
file, and it is stopped with SIGINT, the signal rclpy shuts down cleanly on (SIGTERM can hang
it), then SIGKILL after a timeout. Nothing here imports rclpy: the processes are started before
any rclpy context exists in the caller, so they inherit the caller's ROS environment.

    os.environ.update(private_domain_env())       # before rclpy.init() anywhere
    node = NodeProcess.python_module("artcal_ros.ros.replay", ["--ros-args", "-p", "bag:=..."],
                                     log_dir / "replay.log", cwd=log_dir)
    ...
    status = node.stop()
"""

from __future__ import annotations

import contextlib
import os
import random
import signal
import subprocess
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

# Domain ids above ~200 run out of UDP ports for many participants; 0 is the default everyone
# else on the network uses.
DOMAIN_IDS = (1, 200)


def random_domain_id() -> int:
    """A DDS domain id (1..200) unlikely to be in use by another session on this machine."""
    return random.SystemRandom().randint(*DOMAIN_IDS)


def private_domain_env(domain_id: int | None = None) -> dict[str, str]:
    """The environment variables that put ROS 2 processes on their own domain, this host only.

    Args:
        domain_id: the ROS_DOMAIN_ID to use (default: :func:`random_domain_id`).

    Returns:
        ``{"ROS_DOMAIN_ID": ..., "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}``: set them in
        ``os.environ`` before any rclpy context exists; child processes inherit them.
    """
    return {"ROS_DOMAIN_ID": str(random_domain_id() if domain_id is None else domain_id),
            "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}


def python_path_env(env: Mapping[str, str] | None = None) -> dict[str, str]:
    """``env`` (default: this process's) such that ``python -m artcal_ros...`` started in any
    directory imports the same artcal_ros as this process.

    An installed package (pip, editable or colcon) is found from anywhere and nothing changes.
    Only when this process found the package through ``sys.path[0]`` (a source tree it was
    started in, not installed) does the child need that directory on PYTHONPATH, since the
    child runs in another working directory.
    """
    out = dict(os.environ if env is None else env)
    import artcal_ros

    root = Path(artcal_ros.__file__).resolve().parents[1]
    first = Path(sys.path[0] or os.getcwd()).resolve()
    if root == first:
        parts = [p for p in out.get("PYTHONPATH", "").split(os.pathsep) if p]
        if str(root) not in parts:
            out["PYTHONPATH"] = os.pathsep.join([str(root), *parts])
    return out


class NodeProcess:
    """One node process in its own process group, its stdout and stderr in one log file.

    Attributes:
        name: a name for messages.
        log_path: the log file (created or truncated at start).
        proc: the :class:`subprocess.Popen` (``proc.poll()`` is None while it runs).
        killed: True once :meth:`stop` had to SIGKILL it (it ignored SIGINT).
    """

    def __init__(self, command: Sequence[str], log_path: Path, *, name: str | None = None,
                 cwd: Path | None = None, env: Mapping[str, str] | None = None) -> None:
        """Start ``command``.

        Args:
            command: the program and its arguments (e.g. a console script and ``--ros-args``).
            log_path: where stdout and stderr go; its directory must exist.
            name: for messages (default: the program's file name).
            cwd: working directory (default: this process's).
            env: environment (default: this process's, ROS_DOMAIN_ID and all).
        """
        self.name = name or Path(command[0]).name
        self.log_path = Path(log_path)
        self.killed = False
        with open(self.log_path, "wb") as log:
            # The child holds its own copy of the descriptor: ours can close at once, and the
            # log is then complete on disk whenever the child has flushed.
            self.proc = subprocess.Popen(list(command), cwd=cwd,
                                         env=None if env is None else dict(env),
                                         stdout=log, stderr=subprocess.STDOUT,
                                         stdin=subprocess.DEVNULL, start_new_session=True)

    @classmethod
    def python_module(cls, module: str, args: Sequence[str], log_path: Path, *,
                      name: str | None = None, cwd: Path | None = None,
                      env: Mapping[str, str] | None = None) -> NodeProcess:
        """``python -m module args...`` with this interpreter, importing this artcal_ros.

        Args:
            module: e.g. ``artcal_ros.ros.replay``.
            args: its arguments (``--ros-args`` ...).
            log_path, name, cwd, env: as for the constructor; ``env`` gets PYTHONPATH from
                :func:`python_path_env` when the package is not installed.
        """
        return cls([sys.executable, "-m", module, *args], log_path,
                   name=name or module.rsplit(".", 1)[-1], cwd=cwd, env=python_path_env(env))

    def running(self) -> bool:
        """True while the process has not ended."""
        return self.proc.poll() is None

    def output(self) -> str:
        """Everything it wrote so far, stdout and stderr interleaved (rclpy logs to stderr)."""
        try:
            return self.log_path.read_text(errors="replace")
        except FileNotFoundError:
            return ""

    def tail(self, lines: int = 15) -> str:
        """The last ``lines`` lines of :meth:`output`."""
        return "\n".join(self.output().splitlines()[-lines:])

    def wait(self, timeout: float) -> int:
        """Wait for the process to end by itself; its exit status.

        Raises:
            subprocess.TimeoutExpired: still running after ``timeout`` seconds (it is left
                running: stop it).
        """
        return int(self.proc.wait(timeout))

    def stop(self, timeout: float = 10.0) -> int:
        """SIGINT to its process group, then SIGKILL if it has not ended after ``timeout`` s.

        Returns:
            the exit status (negative: the signal that ended it; ``killed`` tells whether
            SIGKILL was needed). A process that had already ended just gives its status.
        """
        if self.proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.proc.pid, signal.SIGINT)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.killed = True
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait()
        return int(self.proc.returncode)
