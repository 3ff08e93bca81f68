"""The recorded publisher QoS read from bags written by the independent rosbags library and
by BagWriter: metadata.yaml, MCAP channel metadata of a bare file, the enum numbers of bags
before version 9, and publishers that disagree (rosbag2 play's fallback)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import yaml

from artcal_ros.bag import BagReader, BagWriter
from artcal_ros.bag.qos import RecordedQos, recorded_qos

pytestmark = pytest.mark.replay

T0 = 1_700_000_000_000_000_000


def offer(reliability: str, durability: str = "volatile") -> object:
    from rosbags.interfaces import (
        Qos,
        QosDurability,
        QosHistory,
        QosLiveliness,
        QosReliability,
        QosTime,
    )

    never = QosTime(sec=9223372036, nsec=854775807)
    return Qos(history=QosHistory.KEEP_LAST, depth=5,
               reliability=QosReliability[reliability.upper()],
               durability=QosDurability[durability.upper()], deadline=never, lifespan=never,
               liveliness=QosLiveliness.AUTOMATIC, liveliness_lease_duration=never,
               avoid_ros_namespace_conventions=False)


def rosbags_bag(path: Path, offers: dict[str, list[object]], version: int = 9) -> Path:
    """A rosbag2 MCAP directory with one String per topic, each topic offered ``offers``."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_KILTED)
    RString = ts.types["std_msgs/msg/String"]
    with Writer(path, version=version, storage_plugin=StoragePlugin.MCAP) as w:
        for k, (topic, profiles) in enumerate(offers.items()):
            conn = w.add_connection(topic, RString.__msgtype__, typestore=ts,
                                    offered_qos_profiles=profiles)  # type: ignore[arg-type]
            w.write(conn, T0 + k, ts.serialize_cdr(RString(data=topic), RString.__msgtype__))
    return path


def test_metadata_yaml_offers_are_followed(tmp_path: Path) -> None:
    bag = rosbags_bag(tmp_path / "bag", {
        "/be": [offer("best_effort")], "/latched": [offer("reliable", "transient_local")],
        "/plain": [offer("reliable")], "/none": []})
    with BagReader(bag) as r:
        assert recorded_qos(r, "/be") == RecordedQos("best_effort", "volatile", "metadata.yaml")
        assert recorded_qos(r, "/latched") == RecordedQos("reliable", "transient_local",
                                                          "metadata.yaml")
        assert recorded_qos(r, "/plain").reliability == "reliable"
        # no offer recorded: the defaults, as ros2 bag play
        assert recorded_qos(r, "/none") == RecordedQos()


def test_a_bare_mcap_file_has_the_offers_in_its_channel_metadata(tmp_path: Path) -> None:
    bag = rosbags_bag(tmp_path / "bag", {"/be": [offer("best_effort")]})
    (inner,) = bag.glob("*.mcap")
    bare = tmp_path / "bare.mcap"
    shutil.copy(inner, bare)
    with BagReader(bare) as r:
        assert r.metadata is None
        assert recorded_qos(r, "/be") == RecordedQos("best_effort", "volatile", "mcap channel")


def test_bags_before_version_9_store_enum_numbers(tmp_path: Path) -> None:
    bag = rosbags_bag(tmp_path / "bag", {"/be": [offer("best_effort", "transient_local")]},
                      version=8)
    text = (bag / "metadata.yaml").read_text()
    assert "reliability: 2" in text  # what the older format holds, checked to mean it
    with BagReader(bag) as r:
        qos = recorded_qos(r, "/be")
    assert (qos.reliability, qos.durability) == ("best_effort", "transient_local")


def test_disagreeing_publishers_fall_back_to_reliable_with_a_note(tmp_path: Path) -> None:
    bag = rosbags_bag(tmp_path / "bag", {"/mixed": [offer("reliable"), offer("best_effort")]})
    with BagReader(bag) as r:
        qos = recorded_qos(r, "/mixed")
    assert (qos.reliability, qos.durability) == ("reliable", "volatile")
    assert "best_effort and reliable" in qos.note


def test_bag_writer_records_reliable_volatile(tmp_path: Path) -> None:
    for path, storage in ((tmp_path / "dir", "directory"), (tmp_path / "one.mcap", "mcap")):
        with BagWriter(path, storage=storage) as w:  # type: ignore[arg-type]
            w.write("/s", "std_msgs/msg/Header", T0, {"frame_id": "x"})
        with BagReader(path) as r:
            assert recorded_qos(r, "/s") == RecordedQos("reliable", "volatile",
                                                        "metadata.yaml" if r.metadata
                                                        else "mcap channel")


def test_a_hand_edited_metadata_offer_wins_over_the_channel(tmp_path: Path) -> None:
    """metadata.yaml is what rosbag2 reads first; a user editing it changes the replay."""
    path = tmp_path / "dir"
    with BagWriter(path) as w:
        w.write("/s", "std_msgs/msg/Header", T0, {"frame_id": "x"})
    meta = yaml.safe_load((path / "metadata.yaml").read_text())
    info = meta["rosbag2_bagfile_information"]
    info["topics_with_message_count"][0]["topic_metadata"]["offered_qos_profiles"][0][
        "reliability"] = "best_effort"
    (path / "metadata.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
    with BagReader(path) as r:
        assert recorded_qos(r, "/s") == RecordedQos("best_effort", "volatile", "metadata.yaml")
