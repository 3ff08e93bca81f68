"""The calibrator's image subscription: QoS matched to the camera's publishers, losses counted.

A reliable subscriber paired with a reliable publisher gets every frame: lost fragments of a
large message are sent again. A best-effort subscriber paired with the same publisher gets
only the frames whose every fragment arrived the first time, which over Fast DDS's default
transports is a small share of any frame over half a megabyte. So with ``image_qos: auto``
the subscription asks for what the publishers offer, the way ``ros2 topic echo`` and
rosbag2 choose: reliable when every publisher of the topic is reliable, best effort as soon
as one is not (a reliable reader does not match a best-effort writer), and chosen again
whenever the set of publishers changes, on the node's periodic check (:meth:`refresh`, every
:data:`QOS_CHECK_S`). Before any publisher exists the subscription is best effort (it matches
either kind, and the node is subscribed to ``image`` from its start). Once every publisher
has gone the subscription is left as it is, so a driver that restarts is met as before.

The subscription carries no DDS event handlers (matched, incompatible QoS): a handler is a
waitable of its own, and destroying it from one executor thread while another builds its wait
set stops the node's executor (rclpy raises "cannot use Destroyable because destruction was
requested" from the handler's ``add_to_wait_set``). Re-subscribing destroys the old
subscription, so the choice and the incompatible-QoS warning come from the graph instead.

The history is keep-last either way (:data:`IMAGE_DEPTH`): a keep-last reliable reader
acknowledges what it overwrote, so it never holds the camera driver back.

Frames lost on the way are counted from the publication sequence number each message
carries (per publisher): a jump of n + 1 is n frames that never arrived, or that were
replaced in the subscription's queue before the callback took them.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from rclpy.callback_groups import CallbackGroup
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.subscription import MessageInfo, Subscription

MODES = ("auto", "reliable", "best_effort")
# Frames DDS holds for the image callback: the executor thread waits for the interpreter
# while detection and drawing run, and with one slot a frame arriving meanwhile replaces the
# one before it. Five (the depth of ROS's sensor-data profile) carry it over such a wait;
# the detection worker still takes only the newest and counts the rest as dropped (busy).
IMAGE_DEPTH = 5
# How often the node looks at the topic's publishers (:meth:`ImageSubscription.refresh`): a
# publisher that starts after the node is subscribed to within this (plus discovery).
QOS_CHECK_S = 0.2


def image_qos(reliable: bool) -> QoSProfile:
    """Keep-last :data:`IMAGE_DEPTH`, volatile, with the given reliability."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=IMAGE_DEPTH,
                      reliability=ReliabilityPolicy.RELIABLE if reliable
                      else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.VOLATILE)


@dataclass(frozen=True)
class QosChoice:
    """The reliability asked of the image topic, and why.

    Attributes:
        reliable: subscribe reliable (else best effort).
        reason: the choice in words, for the log and the diagnostics.
    """

    reliable: bool
    reason: str

    def text(self) -> str:
        """``reliable (why)`` or ``best effort (why)``."""
        return f"{'reliable' if self.reliable else 'best effort'} ({self.reason})"


def choose_qos(mode: str, publishers_reliable: Sequence[bool]) -> QosChoice:
    """The reliability to subscribe with.

    Args:
        mode: ``auto``, ``reliable`` or ``best_effort`` (the node's ``image_qos``).
        publishers_reliable: for every publisher of the topic now, whether it offers
            reliable delivery.
    """
    if mode == "reliable":
        return QosChoice(True, "image_qos: reliable")
    if mode == "best_effort":
        return QosChoice(False, "image_qos: best_effort")
    n = len(publishers_reliable)
    if n == 0:
        # Best effort matches either kind of publisher, so the first frames are not missed
        # while the choice waits for the publisher to be discovered.
        return QosChoice(False, "auto: no publisher")
    unreliable = n - sum(publishers_reliable)
    if unreliable:
        return QosChoice(False, f"auto: {unreliable} of {n} publisher(s) best effort")
    return QosChoice(True, f"auto: {'the publisher is' if n == 1 else f'all {n} publishers are'}"
                           " reliable")


class SequenceGaps:
    """Frames each publisher sent that never reached the callback, from sequence numbers.

    Not thread safe: fed from one callback group's callbacks only; ``missed`` may be read
    from anywhere (an int).
    """

    def __init__(self) -> None:
        self._last: dict[bytes, int] = {}
        self.missed = 0
        self.known = False  # whether any message carried a sequence number

    def add(self, info: MessageInfo | None) -> None:
        """Count the gap before the message ``info`` describes."""
        if not info:
            return
        seq = info.get("publication_sequence_number")
        if seq is None:
            return
        self.known = True
        key = _publisher_key(info.get("publisher_gid"))
        last = self._last.get(key)
        if last is not None and seq > last + 1:
            self.missed += seq - last - 1
        if last is None or seq > last:
            self._last[key] = seq


def _publisher_key(gid: Any) -> bytes:
    if isinstance(gid, dict):
        gid = gid.get("data", b"")
    try:
        return bytes(gid or b"")
    except TypeError:
        return repr(gid).encode()


class ImageSubscription:
    """The node's subscription to one image topic, re-created when its QoS should change.

    Args:
        node: the node that owns it.
        msg_type: sensor_msgs Image or CompressedImage.
        topic: the topic name (relative names resolve as the node's would).
        callback: called with every message.
        mode: ``auto``, ``reliable`` or ``best_effort``.
        callback_group: the image callbacks' group.
        on_change: called with the new choice whenever the subscription is (re)made.
        on_incompatible: called with a warning, on every check, while a publisher cannot be
            matched (a forced ``reliable`` against a best-effort publisher).
    """

    def __init__(self, node: Node, msg_type: type, topic: str, callback: Callable[[Any], None],
                 *, mode: str, callback_group: CallbackGroup | None = None,
                 on_change: Callable[[QosChoice], None] | None = None,
                 on_incompatible: Callable[[str], None] | None = None) -> None:
        if mode not in MODES:
            raise ValueError(f"image_qos must be one of {', '.join(MODES)}, not {mode!r}")
        self._node = node
        self._type = msg_type
        self.topic = node.resolve_topic_name(topic)
        self._callback = callback
        self._mode = mode
        self._group = callback_group
        self._on_change = on_change
        self._on_incompatible = on_incompatible
        self._lock = threading.Lock()  # refresh() against itself
        self._subscription: Subscription[Any] | None = None
        self.gaps = SequenceGaps()
        self.choice = choose_qos(mode, self._publishers())
        self._subscribe()

    def _publishers(self) -> list[bool]:
        infos = self._node.get_publishers_info_by_topic(self.topic)
        return [i.qos_profile.reliability == ReliabilityPolicy.RELIABLE for i in infos]

    def _subscribe(self) -> None:
        self._subscription = self._node.create_subscription(
            self._type, self.topic, self._on_message, image_qos(self.choice.reliable),
            callback_group=self._group,
            event_callbacks=SubscriptionEventCallbacks(use_default_callbacks=False))
        if self._on_change is not None:
            self._on_change(self.choice)

    def _on_message(self, msg: Any, info: MessageInfo) -> None:
        self.gaps.add(info)
        self._callback(msg)

    def refresh(self) -> bool:
        """Choose again from the publishers now; re-subscribe if the reliability changed.

        Called from one timer (not thread safe against itself beyond its lock). With a
        forced ``reliable`` and a best-effort publisher, warns through ``on_incompatible``.

        Returns:
            True if the subscription was re-made.
        """
        with self._lock:
            publishers = self._publishers()
            if self._mode != "auto":
                self._warn_unmatched(publishers)
                return False
            if not publishers:
                return False  # keep what matched the last publisher until the next one
            choice = choose_qos(self._mode, publishers)
            if choice.reliable == self.choice.reliable:
                self.choice = choice  # the same reliability; the reason may read differently
                return False
            old, self._subscription = self._subscription, None
            if old is not None:
                self._node.destroy_subscription(old)
            self.choice = choice
            self._subscribe()
        return True

    def _warn_unmatched(self, publishers_reliable: Sequence[bool]) -> None:
        unmatched = len(publishers_reliable) - sum(publishers_reliable)
        if not self.choice.reliable or not unmatched or self._on_incompatible is None:
            return
        self._on_incompatible(
            f"{unmatched} publisher(s) of {self.topic} offer best effort, which this "
            f"{self.choice.text()} subscription cannot match: their frames do not arrive "
            "(set image_qos to auto or best_effort)")
