"""The calibrator under a flood of 4K frames: memory, service answers, recovery.

    python -m bench.flood                        # 2 min of 3840x2160 mono8 at 60 Hz (docs)
    python -m bench.flood --flood-seconds 10 --calm-seconds 5     # a short look
    python -m bench.flood --default-transport    # Fast DDS's built-in 512 kB SHM segment

Three phases on one node, each streamed by the publisher child of :mod:`bench.node_load`
(rendered board views, fresh stamps): *before* (a calm stream the node can keep up with,
``--calm-rate``), *flood* (``--rate``, 60 Hz), *after* (the calm stream again). Meanwhile
this process samples the node's resident memory (VmRSS from /proc/<pid>/status) every
0.5 s and calls ``~/calibrate`` every ``--call-every`` seconds on one client, timing each
answer. The node runs with ``min_views`` and ``max_views`` 1000, so every call is answered
at once with "not enough views": the time is the node's responsiveness, not a solve.

By default every process uses ``bench/fastdds_large_shm.xml`` (a 64 MB shared-memory
segment): with Fast DDS's default 512 kB segment most 8 MB best-effort frames are lost
in transit and the node is barely loaded (see README). :func:`run_flood` is the core,
used by the smoke test too.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import statistics
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from artcal_ros.ros.processes import NodeProcess, private_domain_env
from bench.node_load import Listener, LoadSpec, render_frames, vm_rss_kb, wait_for

ROOT = Path(__file__).resolve().parents[1]
LARGE_SHM = ROOT / "artcal_ros" / "ros" / "fastdds_large_shm.xml"
ANSWER_BOUND_S = 2.0  # the figure: a service call is answered within 2 s


@dataclass(frozen=True)
class FloodSpec:
    """One flood run (sizes in pixels, rates in Hz, durations in seconds)."""

    width: int = 3840
    height: int = 2160
    rate_hz: float = 60.0
    flood_s: float = 120.0
    calm_rate_hz: float = 0.5
    calm_s: float = 20.0
    call_every_s: float = 2.0
    views: int = 4
    node_name: str = "flood_calibrator"
    render_downscale: int = 1  # > 1: render this much smaller and scale up (fast, for tests)


@dataclass
class Phase:
    """What one phase measured."""

    name: str
    rate_hz: float
    seconds: float
    sent: int = 0
    seen: int = 0
    processed: int = 0
    dropped: int = 0
    rss_kb: list[tuple[float, int]] = field(default_factory=list)  # (s since run start, kB)
    answers_s: list[float] = field(default_factory=list)  # each ~/calibrate answer time
    unanswered: int = 0  # calls without an answer within 30 s

    @property
    def processed_hz(self) -> float:
        return self.processed / self.seconds if self.seconds else 0.0

    def rss_mb(self) -> tuple[float, float, float]:
        """(first, max, last) VmRSS in MB (0 if not sampled)."""
        if not self.rss_kb:
            return 0.0, 0.0, 0.0
        kb = [k for _, k in self.rss_kb]
        return kb[0] / 1024, max(kb) / 1024, kb[-1] / 1024


@dataclass
class FloodResult:
    spec: FloodSpec
    transport: str
    phases: list[Phase] = field(default_factory=list)
    error: str = ""
    node_exit: int | None = None
    node_log: str = ""


class Caller:
    """Calls ``~/calibrate`` every ``every_s`` on one client from a thread, timing answers
    into the phase set with :meth:`into`."""

    def __init__(self, listener: Listener, service: str, every_s: float) -> None:
        from std_srvs.srv import Trigger

        self._trigger = Trigger
        self._client: Any = listener.node.create_client(Trigger, service)
        if not self._client.wait_for_service(timeout_sec=60.0):
            raise TimeoutError(f"{service} did not appear within 60 s")
        self._every_s = every_s
        self._phase: Phase | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="caller", daemon=True)
        self._thread.start()

    def into(self, phase: Phase | None) -> None:
        self._phase = phase

    def _run(self) -> None:
        while not self._stop.wait(self._every_s):
            phase = self._phase
            if phase is None:
                continue
            t0 = time.monotonic()
            future = self._client.call_async(self._trigger.Request())
            while not future.done() and time.monotonic() - t0 < 30.0:
                time.sleep(0.005)
            if future.done():
                phase.answers_s.append(time.monotonic() - t0)
            else:
                self._client.remove_pending_request(future)
                phase.unanswered += 1

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(35.0)


def _stream(work_dir: Path, frames: Path, topic: str, phase: Phase, node: NodeProcess,
            listener: Listener, t_run: float) -> None:
    """One phase: the publisher child streams; VmRSS sampled; diagnostics deltas."""
    job = {"frames": str(frames), "topic": topic, "encoding": "mono8",
           "rate_hz": phase.rate_hz, "seconds": phase.seconds, "reliable": False,
           "depth": 5, "subscribers": 1, "discovery_timeout": 60.0,
           "result": str(work_dir / f"sent_{phase.name}.json")}
    (work_dir / f"publisher_{phase.name}.json").write_text(json.dumps(job))
    before = listener.last_diagnostics() or {}
    publisher = NodeProcess.python_module(
        "bench.node_load", ["--publisher", str(work_dir / f"publisher_{phase.name}.json")],
        work_dir / f"publisher_{phase.name}.log", name="publisher", cwd=work_dir)
    try:
        while publisher.running():
            kb = vm_rss_kb(node.proc.pid)
            if kb is not None:
                phase.rss_kb.append((time.monotonic() - t_run, kb))
            if not node.running():
                raise RuntimeError(f"the node died (exit {node.proc.returncode})")
            time.sleep(0.5)
    finally:
        publisher.stop(10.0)
    sent = json.loads(Path(job["result"]).read_text())
    if sent.get("error"):
        raise RuntimeError(f"publisher: {sent['error']}")
    phase.sent = int(sent["sent"])
    end_ns = time.time_ns()
    after = wait_for(lambda: listener.last_diagnostics(after_ns=end_ns), 30.0,
                     "diagnostics after the phase")

    def delta(key: str) -> int:
        return int(after.get(key, 0)) - int(before.get(key, 0))

    phase.seen, phase.processed = delta("frames seen"), delta("frames processed")
    phase.dropped = delta("frames dropped (busy)")


def run_flood(spec: FloodSpec, work_dir: Path, *,
              log: Callable[[str], None] = lambda s: print(s, flush=True)) -> FloodResult:
    """Before, flood, after on one node (see the module docstring); the node is stopped
    with SIGINT at the end and its exit status recorded."""
    work_dir.mkdir(parents=True, exist_ok=True)
    profile = os.environ.get("FASTDDS_DEFAULT_PROFILES_FILE", "")
    result = FloodResult(spec, Path(profile).name if profile else "default")
    load = LoadSpec(spec.width, spec.height, spec.rate_hz, spec.flood_s, views=spec.views,
                    node_name=spec.node_name)
    t0 = time.monotonic()
    if spec.render_downscale > 1:
        import cv2

        k = spec.render_downscale
        small = render_frames(LoadSpec(spec.width // k, spec.height // k, spec.rate_hz,
                                       spec.flood_s, views=spec.views))
        frames = [cv2.resize(f, (spec.width, spec.height), interpolation=cv2.INTER_LINEAR)
                  for f in small]
    else:
        frames = render_frames(load)
    np.save(work_dir / "frames.npy", np.stack(frames))
    log(f"  rendered {len(frames)} views {spec.width}x{spec.height} in "
        f"{time.monotonic() - t0:.1f} s ({frames[0].nbytes / 1e6:.1f} MB a frame)")
    node = NodeProcess.python_module(
        "artcal_ros.ros.calibrator",
        ["--ros-args", "-r", f"__node:={spec.node_name}", "-r", f"image:={load.image_topic}",
         "-p", f"output_file:={work_dir / 'camera.yaml'}", "-p", "min_views:=1000",
         "-p", "max_views:=1000"],
        work_dir / "calibrator.log", cwd=work_dir, env={**os.environ, "HOME": str(work_dir)})
    listener: Listener | None = None
    caller: Caller | None = None
    try:
        listener = Listener(load)
        wait_for(listener.matched, 60.0, "the node's topics", node.running)
        wait_for(listener.last_diagnostics, 60.0, "the node's diagnostics", node.running)
        caller = Caller(listener, f"/{spec.node_name}/calibrate", spec.call_every_s)
        t_run = time.monotonic()
        for name, rate, seconds in (("before", spec.calm_rate_hz, spec.calm_s),
                                    ("flood", spec.rate_hz, spec.flood_s),
                                    ("after", spec.calm_rate_hz, spec.calm_s)):
            phase = Phase(name, rate, seconds)
            result.phases.append(phase)
            caller.into(phase)
            log(f"  {name}: {rate:g} Hz for {seconds:g} s")
            _stream(work_dir, work_dir / "frames.npy", load.image_topic, phase, node,
                    listener, t_run)
            caller.into(None)
    except (TimeoutError, RuntimeError, FileNotFoundError) as e:
        result.error = str(e)
        log(f"  ERROR: {e}")
    finally:
        if caller is not None:
            caller.stop()
        if listener is not None:
            listener.close()
        result.node_exit = node.stop(15.0)
        result.node_log = node.output()
    return result


def table(result: FloodResult) -> str:
    """The phases as a Markdown table."""
    lines = ["| phase | rate sent | frames sent / seen / processed / dropped | processed/s "
             "| ~/calibrate answer median / max | unanswered | VmRSS first / max / last |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    for p in result.phases:
        first, peak, last = p.rss_mb()
        med = statistics.median(p.answers_s) if p.answers_s else float("nan")
        top = max(p.answers_s) if p.answers_s else float("nan")
        lines.append(f"| {p.name} | {p.sent / p.seconds:.1f} Hz | {p.sent} / {p.seen} / "
                     f"{p.processed} / {p.dropped} | {p.processed_hz:.2f} | {med:.3f} / "
                     f"{top:.3f} s | {p.unanswered} | {first:.0f} / {peak:.0f} / "
                     f"{last:.0f} MB |")
    return "\n".join(lines)


def verdict(result: FloodResult) -> list[str]:
    """What the run shows against the bounds (memory flat, answers < 2 s, recovery)."""
    out = []
    if result.error:
        out.append(f"error: {result.error}")
    answers = [a for p in result.phases for a in p.answers_s]
    slow = [a for a in answers if a > ANSWER_BOUND_S]
    out.append(f"~/calibrate answers: {len(answers)}, {len(slow)} over {ANSWER_BOUND_S:g} s, "
               f"{sum(p.unanswered for p in result.phases)} unanswered")
    flood = next((p for p in result.phases if p.name == "flood"), None)
    if flood is not None and len(flood.rss_kb) >= 4:
        kb = [k for _, k in flood.rss_kb]
        quarter = len(kb) // 4
        early, late = max(kb[:quarter]) / 1024, max(kb[-quarter:]) / 1024
        out.append(f"flood VmRSS: max {max(kb) / 1024:.0f} MB; max of the first quarter "
                   f"{early:.0f} MB, of the last {late:.0f} MB ({late - early:+.0f} MB)")
    before = next((p for p in result.phases if p.name == "before"), None)
    after = next((p for p in result.phases if p.name == "after"), None)
    if before is not None and after is not None:
        out.append(f"processed/s before {before.processed_hz:.2f}, after "
                   f"{after.processed_hz:.2f} (sent {before.sent} and {after.sent})")
    out.append(f"node exit status on SIGINT: {result.node_exit}")
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.flood",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--width", type=int, default=3840)
    parser.add_argument("--height", type=int, default=2160)
    parser.add_argument("--rate", type=float, default=60.0, help="flood rate, Hz")
    parser.add_argument("--flood-seconds", type=float, default=120.0)
    parser.add_argument("--calm-rate", type=float, default=0.5, help="before/after rate, Hz")
    parser.add_argument("--calm-seconds", type=float, default=20.0)
    parser.add_argument("--call-every", type=float, default=2.0, help="seconds between calls")
    parser.add_argument("--default-transport", action="store_true",
                        help="Fast DDS's built-in transports instead of the 64 MB SHM profile")
    parser.add_argument("--keep", type=Path, help="work directory to keep (logs)")
    parser.add_argument("--json", type=Path, help="also write the phases here")
    args = parser.parse_args(argv)
    # Before any rclpy context exists here: the node and the publishers inherit it.
    if "ROS_DOMAIN_ID" not in os.environ:
        os.environ.update(private_domain_env())
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    if args.default_transport:
        os.environ["ARTCAL_FASTDDS_PROFILE"] = "0"  # the node's own large segment too
    else:
        os.environ["FASTDDS_DEFAULT_PROFILES_FILE"] = str(LARGE_SHM)
    spec = FloodSpec(args.width, args.height, args.rate, args.flood_seconds, args.calm_rate,
                     args.calm_seconds, args.call_every)
    print(f"{spec.width}x{spec.height} mono8 flood at {spec.rate_hz:g} Hz for "
          f"{spec.flood_s:g} s (load {os.getloadavg()[0]:.1f})", flush=True)
    with contextlib.ExitStack() as stack:
        work = args.keep or Path(stack.enter_context(tempfile.TemporaryDirectory(
            prefix="artcal_flood_")))
        result = run_flood(spec, work)
    print()
    print(f"transport: {result.transport}; load after {os.getloadavg()[0]:.1f}")
    print(table(result))
    print()
    for line in verdict(result):
        print(f"- {line}")
    if args.json:
        args.json.write_text(json.dumps({"transport": result.transport, "phases": [
            {**p.__dict__, "rss_kb": p.rss_kb} for p in result.phases]}, indent=1))
    return 1 if result.error or result.node_exit != 0 else 0


if __name__ == "__main__":
    sys.exit(main())
