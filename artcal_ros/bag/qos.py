"""The QoS a recorded topic's publishers offered, as rosbag2 stores it (no rclpy).

rosbag2 keeps each topic's ``offered_qos_profiles`` in metadata.yaml and, with the MCAP
storage, in the channel's metadata as well: a list of profiles, one per publisher seen
while recording. Bags of format version 9 (jazzy on) store a YAML list of mappings with
policy names (``reliability: reliable``); older ones a YAML string of the same list with
rmw's enum numbers (``reliability: 1``). Both are read here.

``ros2 bag play`` offers what the recording's publishers offered: a policy on which every
recorded profile agrees is kept; with no profile, or with profiles that disagree, it
falls back to its default (reliable, volatile). :func:`recorded_qos` decides the same way.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import yaml
from mcap.reader import make_reader

from artcal_ros.bag.reader import BagReader

RELIABILITIES = ("reliable", "best_effort")
DURABILITIES = ("volatile", "transient_local")
# rmw_qos_reliability_policy_e / rmw_qos_durability_policy_e, as bags before version 9 hold
# them; 0 is the system default, which says nothing about the publisher.
_RELIABILITY_ENUM = {1: "reliable", 2: "best_effort"}
_DURABILITY_ENUM = {1: "transient_local", 2: "volatile"}


@dataclass(frozen=True)
class RecordedQos:
    """The reliability and durability to republish a recorded topic with.

    Attributes:
        reliability: ``reliable`` or ``best_effort``.
        durability: ``volatile`` or ``transient_local``.
        source: where the offers were read (``metadata.yaml``, ``mcap channel``), or
            ``none recorded`` (the defaults).
        note: why a recorded offer was not followed (profiles that disagree), else "".
    """

    reliability: str = "reliable"
    durability: str = "volatile"
    source: str = "none recorded"
    note: str = ""


def _profiles(value: Any) -> list[dict[str, Any]]:
    """The profiles of one ``offered_qos_profiles`` entry (a list, or YAML text of one)."""
    if isinstance(value, str):
        try:
            value = yaml.safe_load(value) if value.strip() else []
        except yaml.YAMLError:
            return []
    if not isinstance(value, list):
        return []
    return [p for p in value if isinstance(p, dict)]


def _policy(profile: dict[str, Any], key: str, enum: dict[int, str],
            names: tuple[str, ...]) -> str | None:
    value = profile.get(key)
    if isinstance(value, bool):
        return None
    if isinstance(value, int):
        return enum.get(value)
    text = str(value).strip().lower() if value is not None else ""
    return text if text in names else None


def offered_profiles(reader: BagReader, topic: str) -> tuple[list[dict[str, Any]], str]:
    """The QoS profiles recorded for ``topic`` and where they were found.

    metadata.yaml first (``ros2 bag record`` writes both), then the channel metadata of
    the .mcap files (a bare .mcap file has only that).

    Returns:
        (profiles, source): the profiles as mappings, and ``metadata.yaml``, ``mcap
        channel`` or ``none recorded`` (with an empty list).
    """
    for entry in (reader.metadata or {}).get("topics_with_message_count") or []:
        meta = entry.get("topic_metadata") if isinstance(entry, dict) else None
        if isinstance(meta, dict) and meta.get("name") == topic:
            found = _profiles(meta.get("offered_qos_profiles"))
            if found:
                return found, "metadata.yaml"
    for path in reader.files:
        try:
            with open(path, "rb") as fh:
                summary = make_reader(fh).get_summary()
        except Exception:  # a damaged file: playing it reports the damage, not this
            continue
        for channel in (summary.channels.values() if summary is not None else ()):
            if channel.topic == topic:
                found = _profiles(channel.metadata.get("offered_qos_profiles", ""))
                if found:
                    return found, "mcap channel"
    return [], "none recorded"


def recorded_qos(reader: BagReader, topic: str) -> RecordedQos:
    """How ``ros2 bag play`` would offer ``topic``: see the module docstring."""
    profiles, source = offered_profiles(reader, topic)
    if not profiles:
        return RecordedQos()
    reliabilities = {_policy(p, "reliability", _RELIABILITY_ENUM, RELIABILITIES)
                     for p in profiles}
    durabilities = {_policy(p, "durability", _DURABILITY_ENUM, DURABILITIES) for p in profiles}
    chosen = {"reliability": "reliable", "durability": "volatile"}
    notes = []
    for key, seen in (("reliability", reliabilities), ("durability", durabilities)):
        known = {k for k in seen if k is not None}
        if len(seen) == 1 and known:
            chosen[key] = known.pop()
        elif len(known) > 1:
            notes.append(f"the {len(profiles)} recorded publishers offered {key} "
                         f"{' and '.join(sorted(str(k) for k in known))}; using "
                         f"{chosen[key]}")
    return RecordedQos(chosen["reliability"], chosen["durability"], source, "; ".join(notes))
