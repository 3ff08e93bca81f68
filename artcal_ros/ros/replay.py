"""The replay node: play a rosbag2 MCAP recording on its recorded topics and types.

``ros2 run artcal_ros replay --ros-args -p bag:=bags/sample -p rate:=1.0 -p loop:=false``

Parameters:
  bag                   rosbag2 directory (metadata.yaml + .mcap) or a bare .mcap file
  rate                  1.0 plays at the recorded pace, 2.0 twice as fast; 0 ignores the
                        recorded timing and sends as fast as it can (reliable subscribers
                        get every message; a keep-latest subscriber such as the calibrator
                        only the newest, so give it a rate it can keep up with)
  loop                  start again at the end (until Ctrl-C)
  start_offset          seconds of the recording to skip at the start
  topics                recorded topics to play (empty: all)
  remap                 ["from:=to", ...] to publish a recorded topic under another name
                        (standard ``--ros-args -r from:=to`` remapping works as well)
  wait_for_subscribers  wait until some topic has a subscriber before playing
  wait_timeout          seconds to wait for one; then play anyway (with a warning)

Messages are republished as recorded (serialized CDR bytes), so any type whose
interface package is installed can be played without decoding. Exit status: 0
at the end (or on Ctrl-C), 1 for a bag that cannot be read (one line naming the
file and where), 2 for a bad parameter.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import rclpy
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.duration import Duration
from rclpy.exceptions import ParameterUninitializedException
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

from artcal_ros.bag import BagMessage, BagReader
from artcal_ros.core.errors import BagError, ParameterError
from artcal_ros.ros.msgs import message_class
from artcal_ros.ros.signals import StopSignals


@dataclass(frozen=True)
class ReplayConfig:
    """The replay node's validated parameters (see the module docstring)."""

    bag: str
    rate: float = 1.0
    loop: bool = False
    start_offset: float = 0.0
    topics: tuple[str, ...] = ()
    remap: tuple[tuple[str, str], ...] = ()
    wait_for_subscribers: bool = True
    wait_timeout: float = 30.0

    def target(self, topic: str) -> str:
        """The name a recorded topic is published under."""
        return dict(self.remap).get(topic, topic)


_SCALARS: dict[str, tuple[Any, str]] = {
    "bag": ("", "rosbag2 directory or .mcap file to play"),
    "rate": (1.0, "playback speed factor; 0 = as fast as reliable subscribers acknowledge"),
    "loop": (False, "start again at the end"),
    "start_offset": (0.0, "seconds of the recording to skip"),
    "wait_for_subscribers": (True, "wait for a subscriber before playing"),
    "wait_timeout": (30.0, "seconds to wait for a subscriber, then play anyway"),
}
_ARRAYS = {"topics": "recorded topics to play (empty: all)",
           "remap": "list of from:=to topic renamings"}


def _number(name: str, value: Any, *, minimum: float = 0.0) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParameterError(f"parameter '{name}': expected a number, got {value!r}")
    if value < minimum:
        raise ParameterError(f"parameter '{name}': {value} must be >= {minimum:g}")
    return float(value)


def _flag(name: str, value: Any) -> bool:
    if not isinstance(value, bool):
        raise ParameterError(f"parameter '{name}': expected true or false, got {value!r}")
    return value


def parse_remap(entries: Sequence[str]) -> tuple[tuple[str, str], ...]:
    """``["from:=to", ...]`` as pairs; ParameterError naming ``remap`` for a malformed one."""
    out = []
    for entry in entries:
        src, sep, dst = entry.partition(":=")
        if not sep or not src.strip() or not dst.strip():
            raise ParameterError(f"parameter 'remap': {entry!r} is not of the form from:=to")
        out.append((src.strip(), dst.strip()))
    return tuple(out)


def declare_replay_parameters(node: Node) -> ReplayConfig:
    """Declare the replay parameters (with descriptions) and return them validated.

    Raises:
        ParameterError: a bad or missing value, naming the parameter.
    """
    for name, (default, text) in _SCALARS.items():
        node.declare_parameter(name, default, ParameterDescriptor(
            name=name, description=text, read_only=True, dynamic_typing=True))
    arrays: dict[str, list[str]] = {}
    for name, text in _ARRAYS.items():
        node.declare_parameter(name, Parameter.Type.STRING_ARRAY, ParameterDescriptor(
            name=name, description=text, read_only=True))
        try:
            arrays[name] = list(node.get_parameter(name).value or [])
        except ParameterUninitializedException:
            arrays[name] = []
    value = {name: node.get_parameter(name).value for name in _SCALARS}
    bag = value["bag"]
    if not isinstance(bag, str) or not bag:
        raise ParameterError("parameter 'bag': give the recording to play, "
                             "e.g. --ros-args -p bag:=bags/sample")
    return ReplayConfig(
        bag=bag, rate=_number("rate", value["rate"]), loop=_flag("loop", value["loop"]),
        start_offset=_number("start_offset", value["start_offset"]),
        topics=tuple(arrays["topics"]), remap=parse_remap(arrays["remap"]),
        wait_for_subscribers=_flag("wait_for_subscribers", value["wait_for_subscribers"]),
        wait_timeout=_number("wait_timeout", value["wait_timeout"]))


def _latched(reader: BagReader, topic: str) -> bool:
    """Whether the recording says ``topic`` was offered transient local (e.g. /tf_static)."""
    for entry in (reader.metadata or {}).get("topics_with_message_count") or []:
        tm = entry.get("topic_metadata") or {}
        if tm.get("name") == topic:
            return "transient_local" in str(tm.get("offered_qos_profiles", ""))
    return False


class Player:
    """Publishes a bag's messages with the recorded timing (see the module docstring).

    Raises:
        BagError: the bag cannot be opened; ParameterError: nothing to play.
    """

    def __init__(self, node: Node, config: ReplayConfig, *,
                 stop: threading.Event | None = None) -> None:
        self.node = node
        self.config = config
        self._stop = stop or threading.Event()  # set: stop playing (a stop signal came)
        self.log = node.get_logger()
        self.reader = BagReader(config.bag)
        recorded = self.reader.topics
        unknown = [t for t in config.topics if t not in recorded]
        if unknown:
            raise ParameterError(f"parameter 'topics': {', '.join(unknown)} not in the bag "
                                 f"(it has {', '.join(sorted(recorded)) or 'no topics'})")
        wanted = config.topics or tuple(sorted(recorded))
        self.publishers: dict[str, Publisher] = {}
        for topic in wanted:
            try:
                cls = message_class(recorded[topic])
            except (ImportError, ValueError) as e:
                self.log.warning(f"skipping {topic}: type {recorded[topic]!r} unavailable ({e})")
                continue
            # At rate 0 nothing paces the stream: keep every message until reliable
            # subscribers have it, so they lose none however far behind they fall.
            qos = QoSProfile(history=HistoryPolicy.KEEP_ALL if config.rate == 0
                             else HistoryPolicy.KEEP_LAST, depth=10,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL
                             if _latched(self.reader, topic) else DurabilityPolicy.VOLATILE)
            self.publishers[topic] = node.create_publisher(cls, config.target(topic), qos)
        if not self.publishers:
            raise ParameterError(f"{config.bag}: none of its topics can be played")
        self.played = 0

    def _ok(self) -> bool:
        return rclpy.ok() and not self._stop.is_set()

    def wait_for_subscribers(self) -> bool:
        """Poll until a publisher has a subscriber (True), or the timeout or Ctrl-C (False)."""
        deadline = time.monotonic() + self.config.wait_timeout
        while self._ok() and time.monotonic() < deadline:
            if any(p.get_subscription_count() > 0 for p in self.publishers.values()):
                # Discovery is two-sided: give the subscriber a moment to match us as well,
                # or the first messages can be lost.
                self._sleep_until(time.monotonic() + 0.5)
                return True
            time.sleep(0.05)
        return False

    def _sleep_until(self, when: float) -> bool:
        while self._ok():
            left = when - time.monotonic()
            if left <= 0:
                return True
            time.sleep(min(left, 0.05))
        return False

    def _messages(self) -> Iterator[BagMessage]:
        skip_until: int | None = None
        for m in self.reader.messages(list(self.publishers)):
            if skip_until is None:
                skip_until = m.log_time_ns + int(self.config.start_offset * 1e9)
            if m.log_time_ns >= skip_until:
                yield m

    def play(self) -> None:
        """Play once, or until Ctrl-C with ``loop``.

        Raises:
            BagError: where the recording is broken (after the messages before it).
        """
        rate = self.config.rate
        while self._ok():
            wall0: float | None = None
            bag0 = 0
            for m in self._messages():
                if not self._ok():
                    return
                if wall0 is None:
                    wall0, bag0 = time.monotonic(), m.log_time_ns
                if rate > 0 and not self._sleep_until(
                        wall0 + (m.log_time_ns - bag0) * 1e-9 / rate):
                    return
                pub = self.publishers[m.topic]
                pub.publish(m.data)
                self.played += 1
            if not self.config.loop:
                return

    def flush(self) -> None:
        """Wait (briefly) until reliable subscribers have every message sent."""
        t0 = time.monotonic()
        for pub in self.publishers.values():
            pub.wait_for_all_acked(Duration(seconds=1))
        self.log.debug(f"flushed in {time.monotonic() - t0:.2f} s")

    def close(self) -> None:
        self.reader.close()


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run artcal_ros replay`` (console script ``replay``)."""
    stop = StopSignals.install()
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("replay")
    log = node.get_logger()
    status = 0
    player: Player | None = None
    try:
        player = Player(node, declare_replay_parameters(node), stop=stop.event)
        names = ", ".join(f"{t} -> {p.topic_name}" if t != p.topic_name else t
                          for t, p in player.publishers.items())
        log.info(f"playing {player.config.bag}: {names}")
        if player.config.wait_for_subscribers and not player.wait_for_subscribers() \
                and not stop.is_set():
            log.warning(f"no subscriber after {player.config.wait_timeout:g} s; playing anyway")
        t0 = time.monotonic()
        player.play()
        if not stop.is_set():
            player.flush()
            log.info(f"played {player.played} messages in {time.monotonic() - t0:.1f} s")
    except ParameterError as e:
        log.fatal(f"refusing to start: {e}")
        status = 2
    except BagError as e:
        log.error(f"cannot play the bag: {e}")
        status = 1
    except ExternalShutdownException:
        pass
    finally:
        if player is not None:
            player.close()
        node.destroy_node()
        rclpy.try_shutdown()
    return status


if __name__ == "__main__":
    sys.exit(main())
