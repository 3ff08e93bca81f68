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
  wait_for_subscribers  wait until some topic has a subscriber (and their number has held
                        for a second: a subscriber may re-subscribe once it has seen us)
  wait_timeout          seconds to wait for one; then play anyway (with a warning)
  qos                   the reliability each topic is offered with: ``recorded`` (default: as
                        the recording's publishers offered it, like ``ros2 bag play``; from
                        the bag's ``offered_qos_profiles``, reliable when none is recorded or
                        the recorded publishers disagree), ``reliable`` or ``best_effort``
                        (every topic). Durability always follows the recording (a latched
                        topic stays transient local).
  until_topic           a sensor_msgs/CameraInfo topic (empty: none). With ``loop``, playing
                        stops at the end of the pass during which a message arrived on it,
                        e.g. the calibrator's ``camera_info`` after a successful
                        ``~/calibrate`` (subscribed reliable and transient local, so a
                        latched result counts too)

Messages are republished as recorded (serialized CDR bytes), so any type whose
interface package is installed can be played without decoding. The node's Fast DDS
participant gets the package's large shared-memory segment unless the user chose a
transport setup (:mod:`artcal_ros.ros.transport`), so large frames offered best effort
arrive. At ``rate`` 0 a reliable topic keeps every message until its subscribers have
acknowledged it; a best-effort one is sent as fast as it is read. Exit status: 0 at the
end (also when ``until_topic`` ended a loop, or on Ctrl-C), 1 for a bag that cannot be
read (one line naming the file and where), 2 for a bad parameter.
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
from rclpy.exceptions import InvalidTopicNameException, ParameterUninitializedException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import CameraInfo

from artcal_ros.bag import BagMessage, BagReader
from artcal_ros.bag.qos import RecordedQos, recorded_qos
from artcal_ros.core.errors import BagError, ParameterError
from artcal_ros.ros.command_line import CommandHelp, ParamHelp, handle_arguments, init_ros
from artcal_ros.ros.msgs import message_class
from artcal_ros.ros.signals import StopSignals
from artcal_ros.ros.transport import use_large_shared_memory


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
    qos: str = "recorded"
    until_topic: str = ""

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
    "qos": ("recorded", "publisher reliability: recorded, reliable or best_effort"),
    "until_topic": ("", "CameraInfo topic: with loop, stop after the pass it got a message"),
}
QOS_CHOICES = ("recorded", "reliable", "best_effort")
_RELIABILITY = {"reliable": ReliabilityPolicy.RELIABLE,
                "best_effort": ReliabilityPolicy.BEST_EFFORT}
_DURABILITY = {"volatile": DurabilityPolicy.VOLATILE,
               "transient_local": DurabilityPolicy.TRANSIENT_LOCAL}
# Discovery is two-sided, and a subscriber that chooses its QoS from ours (the calibrator's
# image_qos auto) replaces its subscription once it has seen us: messages sent before the
# subscription it keeps has matched are lost. Play once the matched count has held this long
# (the calibrator looks at the graph every 0.2 s, and discovery under load takes seconds).
SETTLE_S = 2.0
# A result latched before we subscribed must still reach us.
UNTIL_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                       reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL)
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


def _choice(name: str, value: Any, choices: Sequence[str]) -> str:
    if value not in choices:
        raise ParameterError(f"parameter '{name}': {value!r} is not one of "
                             f"{', '.join(choices)}")
    return str(value)


def _text(name: str, value: Any) -> str:
    if not isinstance(value, str):
        raise ParameterError(f"parameter '{name}': expected a string, got {value!r}")
    return value.strip()


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
        wait_timeout=_number("wait_timeout", value["wait_timeout"]),
        qos=_choice("qos", value["qos"], QOS_CHOICES),
        until_topic=_text("until_topic", value["until_topic"]))


def publisher_qos(recorded: RecordedQos, config: ReplayConfig) -> QoSProfile:
    """The profile to offer a recorded topic with: its recorded durability, the reliability
    ``config.qos`` asks for (see the module docstring)."""
    reliability = recorded.reliability if config.qos == "recorded" else config.qos
    # At rate 0 nothing paces the stream: a reliable topic keeps every message until its
    # subscribers have it, so they lose none however far behind they fall.
    keep_all = config.rate == 0 and reliability == "reliable"
    return QoSProfile(history=HistoryPolicy.KEEP_ALL if keep_all else HistoryPolicy.KEEP_LAST,
                      depth=10, reliability=_RELIABILITY[reliability],
                      durability=_DURABILITY[recorded.durability])


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
        self.offered: dict[str, str] = {}  # topic -> how it is offered, for the log
        for topic in wanted:
            try:
                cls = message_class(recorded[topic])
            except (ImportError, ValueError) as e:
                self.log.warning(f"skipping {topic}: type {recorded[topic]!r} unavailable ({e})")
                continue
            offer = recorded_qos(self.reader, topic)
            if offer.note and config.qos == "recorded":
                self.log.warning(f"{topic}: {offer.note}")
            qos = publisher_qos(offer, config)
            self.publishers[topic] = node.create_publisher(cls, config.target(topic), qos)
            self.offered[topic] = (
                f"{_name(qos.reliability)}, {_name(qos.durability)}: " + (
                    f"recorded, {offer.source}" if config.qos == "recorded"
                    else "the qos parameter"))
        if not self.publishers:
            raise ParameterError(f"{config.bag}: none of its topics can be played")
        self.played = 0
        self.passes = 0  # complete passes through the recording
        self._until_seen = threading.Event()
        self._executor: SingleThreadedExecutor | None = None
        if config.until_topic:
            try:
                node.create_subscription(CameraInfo, config.until_topic,
                                         lambda _msg: self._until_seen.set(), UNTIL_QOS)
            except InvalidTopicNameException as e:
                raise ParameterError(f"parameter 'until_topic': {config.until_topic!r} is not "
                                     f"a valid topic name ({str(e).splitlines()[0]})") from None
            # Spun only between passes, here: it takes what arrived meanwhile.
            self._executor = SingleThreadedExecutor(context=node.context)
            self._executor.add_node(node)

    @property
    def until_resolved(self) -> str:
        """``until_topic`` as resolved by the node (remappings and namespace applied)."""
        return self.node.resolve_topic_name(self.config.until_topic)

    def until_arrived(self) -> bool:
        """Whether a message came on ``until_topic`` (False when none is set)."""
        if self._executor is None:
            return False
        for _ in range(10):  # a few rounds: other work (parameter requests) may come first
            if self._until_seen.is_set():
                break
            self._executor.spin_once(timeout_sec=0.0)
        return self._until_seen.is_set()

    def _ok(self) -> bool:
        return rclpy.ok() and not self._stop.is_set()

    def wait_for_subscribers(self) -> bool:
        """Poll until the publishers have subscribers and their number has held for
        SETTLE_S (True), or the timeout or Ctrl-C (False, unless some had matched)."""
        deadline = time.monotonic() + self.config.wait_timeout
        count, since = 0, time.monotonic()
        while self._ok() and time.monotonic() < deadline:
            now = time.monotonic()
            matched = sum(p.get_subscription_count() for p in self.publishers.values())
            if matched != count:
                count, since = matched, now
            elif count > 0 and now - since >= SETTLE_S:
                return True
            time.sleep(0.05)
        return count > 0

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
            self.passes += 1
            if not self.config.loop:
                return
            if self.until_arrived():
                self.log.info(f"a message came on {self.until_resolved}: stopping after "
                              f"{self.passes} passes")
                return

    def flush(self) -> None:
        """Wait (briefly) until reliable subscribers have every message sent."""
        t0 = time.monotonic()
        for pub in self.publishers.values():
            pub.wait_for_all_acked(Duration(seconds=1))
        self.log.debug(f"flushed in {time.monotonic() - t0:.2f} s")

    def close(self) -> None:
        if self._executor is not None:
            self._executor.shutdown(timeout_sec=1.0)
        self.reader.close()


def _name(policy: Any) -> str:
    """``ReliabilityPolicy.BEST_EFFORT`` as ``best_effort``."""
    return str(policy.name).lower()


HELP = CommandHelp(
    "replay",
    "Plays a rosbag2 MCAP recording (a directory or a bare .mcap file) on its recorded topics "
    "and types, with the recorded timing scaled by rate.",
    (*(ParamHelp(name, default, text, "required" if name == "bag" else "")
       for name, (default, text) in _SCALARS.items()),
     *(ParamHelp(name, [], text) for name, text in _ARRAYS.items())),
    "replay --ros-args -p bag:=bags/sample -p rate:=1.0 -p loop:=false")


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run artcal_ros replay`` (console script ``replay``); ``args``:
    the whole command line as ``sys.argv`` (default: ``sys.argv``)."""
    status = handle_arguments(sys.argv if args is None else args, HELP)
    if status is not None:
        return status
    stop = StopSignals.install()
    # a camera's large frames sent best effort arrive only through a segment that holds them
    transport = use_large_shared_memory()  # before rclpy creates the participant
    if not init_ros(args, HELP.program, signal_handler_options=SignalHandlerOptions.NO):
        return 2
    node = rclpy.create_node("replay")
    log = node.get_logger()
    status = 0
    player: Player | None = None
    try:
        player = Player(node, declare_replay_parameters(node), stop=stop.event)
        names = ", ".join((f"{t} -> {p.topic_name}" if t != p.topic_name else t)
                          + f" ({player.offered[t]})" for t, p in player.publishers.items())
        log.info(f"playing {player.config.bag}: {names}; DDS transport: {transport}")
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
