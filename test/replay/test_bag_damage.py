"""Bags as users have them: compressed chunks, messages out of order, no messages, a
metadata.yaml that is garbled, types that cannot be decoded, topics that are not there,
files cut short, and random damage (property-based): the reader yields messages or raises
BagError, nothing else."""

from __future__ import annotations

import contextlib
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap.writer import Writer as McapWriter

from artcal_ros.bag import BagReader, BagWriter
from artcal_ros.core.errors import BagError
from artcal_ros.core.images import image_to_numpy, numpy_to_image
from test.replay.test_bag import IMAGE, INFO, T0, info_fields

pytestmark = pytest.mark.filterwarnings("ignore")


def frame(i: int) -> np.ndarray:
    """A small mono8 frame that tells which one it is: every pixel is ``i``."""
    return np.full((6, 8), i % 256, np.uint8)


def write_bag(path: Path, order: list[int], *, compression: str = "zstd",
              chunk_size: int = 400, storage: str | None = None) -> None:
    with BagWriter(path, storage=storage, compression=compression,  # type: ignore[arg-type]
                   chunk_size=chunk_size) as w:
        for i in order:
            w.write("/cam", IMAGE, T0 + i, numpy_to_image(frame(i), "mono8", T0 + i))
            if i % 2 == 0:
                w.write("/cam/info", INFO, T0 + i, info_fields(T0 + i))


def frames_read(reader: BagReader, on_damage: str = "raise") -> list[int]:
    """Which frames the bag gives back, in the order it gives them."""
    messages = reader.messages("/cam", on_damage=on_damage)  # type: ignore[arg-type]
    return [int(image_to_numpy(m.decode())[0, 0]) for m in messages]


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_zstd_and_lz4_chunks_are_read_back(tmp_path: Path, compression: str) -> None:
    bag = tmp_path / compression
    write_bag(bag, list(range(12)), compression=compression)
    with BagReader(bag) as r:
        assert frames_read(r) == list(range(12))
        assert r.message_count == 18 and r.warnings == []
    with open(bag / f"{compression}_0.mcap", "rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None and len(summary.chunk_indexes) > 3
    # the chunks really are compressed as asked
    assert {ci.compression for ci in summary.chunk_indexes} == {
        "" if compression == "none" else compression}


@pytest.mark.parametrize("chunk_size", [400, 10**6])
def test_out_of_order_timestamps_come_in_log_time_order(tmp_path: Path,
                                                        chunk_size: int) -> None:
    bag = tmp_path / "ooo"
    order = [5, 1, 7, 0, 3, 6, 2, 4]
    write_bag(bag, order, chunk_size=chunk_size)
    with BagReader(bag) as r:
        stamps = [m.log_time_ns - T0 for m in r.messages("/cam")]
        assert r.warnings == []
    assert stamps == sorted(order)


def test_out_of_order_in_a_file_without_index_is_read_in_file_order_and_said(
        tmp_path: Path) -> None:
    bag = tmp_path / "ooo.mcap"
    order = [5, 1, 7, 0, 3]
    write_bag(bag, order)
    data = bag.read_bytes()
    bag.write_bytes(data[:-40])  # the footer is gone: no index
    with BagReader(bag) as r:
        got = [m.log_time_ns - T0 for m in r.messages("/cam", on_damage="stop")]
        warnings = list(r.warnings)
    assert got == order
    assert any("not in log-time order" in w and "order they were written" in w
               for w in warnings)


def test_zero_messages(tmp_path: Path) -> None:
    with BagWriter(tmp_path / "empty"):
        pass
    with BagReader(tmp_path / "empty") as r:
        assert r.topics == {} and r.message_count == 0 and list(r) == []
        assert r.topics_text() == "no topics"


GARBLED = {
    "not YAML": "::: [",
    "not a mapping": "just a string",
    "information not a mapping": "rosbag2_bagfile_information: 5",
    "file list not a list": ("rosbag2_bagfile_information:\n  storage_identifier: mcap\n"
                             "  relative_file_paths: 7\n"),
    "count not a number": ("rosbag2_bagfile_information:\n  storage_identifier: mcap\n"
                           "  relative_file_paths: [bag_0.mcap]\n  message_count: lots\n"),
    "topics not entries": ("rosbag2_bagfile_information:\n  storage_identifier: mcap\n"
                           "  relative_file_paths: [bag_0.mcap]\n"
                           "  topics_with_message_count: [5, {topic_metadata: 3}]\n"),
    "lists a missing file": ("rosbag2_bagfile_information:\n  storage_identifier: mcap\n"
                             "  relative_file_paths: [gone_0.mcap]\n"),
    "empty": "",
    "not UTF-8": "\udcff\udcfe",
}
GARBLED_SAYS = {
    "not YAML": "cannot read it", "not a mapping": "no rosbag2_bagfile_information",
    "information not a mapping": "no rosbag2_bagfile_information",
    "file list not a list": "relative_file_paths is 7", "count not a number":
    "message_count is 'lots'", "topics not entries": "topics_with_message_count is not",
    "lists a missing file": "lists files that do not exist", "empty":
    "no rosbag2_bagfile_information", "not UTF-8": "cannot read it",
}


@pytest.mark.parametrize("case", list(GARBLED))
def test_garbled_metadata_falls_back_to_the_mcap_and_says_why(tmp_path: Path,
                                                              case: str) -> None:
    bag = tmp_path / "bag"
    write_bag(bag, list(range(4)))
    meta = bag / "metadata.yaml"
    meta.write_bytes(GARBLED[case].encode("utf-8", "surrogateescape"))
    with BagReader(bag) as r:
        assert frames_read(r) == [0, 1, 2, 3]
        assert r.topics == {"/cam": IMAGE, "/cam/info": INFO} and r.message_count == 6
        assert len(r.warnings) == 1
        assert str(meta) in r.warnings[0] and GARBLED_SAYS[case] in r.warnings[0]
        assert "reading the .mcap files" in r.warnings[0] and "bag_0.mcap" in r.warnings[0]
    # without an .mcap to fall back to, it is a BagError naming the file and the problem
    alone = tmp_path / "alone"
    alone.mkdir()
    shutil.copy(meta, alone / "metadata.yaml")
    with pytest.raises(BagError) as err:
        BagReader(alone)
    assert str(alone / "metadata.yaml") in str(err.value)
    assert GARBLED_SAYS[case] in str(err.value)


def test_unknown_message_types_are_listed_yielded_and_say_why_they_cannot_decode(
        tmp_path: Path, capfd: pytest.CaptureFixture) -> None:
    bag = tmp_path / "mixed.mcap"
    with open(bag, "wb") as fh:
        w = McapWriter(fh)
        w.start(profile="ros2")
        json_schema = w.register_schema("foo/msg/Bar", "jsonschema", b"{}")
        broken = w.register_schema("bad/msg/Def", "ros2msg", b"notatype !! x y z")
        ok = w.register_schema("pkg/msg/Count", "ros2msg", b"int32 x")
        channels = {"/json": w.register_channel("/json", "json", json_schema),
                    "/none": w.register_channel("/none", "cdr", 0),
                    "/broken": w.register_channel("/broken", "cdr", broken),
                    "/count": w.register_channel("/count", "cdr", ok)}
        for i in range(2):
            for topic, cid in channels.items():
                data = b"\x00\x01\x00\x00\x05\x00\x00\x00" if topic == "/count" else b"{}"
                w.add_message(cid, log_time=i, publish_time=i, data=data)
        w.finish()
    with BagReader(bag) as r:
        assert r.topics == {"/json": "foo/msg/Bar", "/none": "", "/broken": "bad/msg/Def",
                            "/count": "pkg/msg/Count"}
        got = list(r)
        assert len(got) == 8
        assert [m.decode().x for m in got if m.topic == "/count"] == [5, 5]
        reasons = {"/json": "stored as 'json' with a 'jsonschema' schema",
                   "/none": "the channel has no schema",
                   "/broken": "the message definition of bad/msg/Def does not parse"}
        for m in got:
            if m.topic in reasons:
                with pytest.raises(BagError, match=reasons[m.topic]):
                    m.decode()
    assert "Error processing" not in capfd.readouterr().err  # said once, in the BagError


def test_a_topic_that_is_not_there_lists_the_topics_with_their_types(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    write_bag(bag, [0, 1])
    with BagReader(bag) as r, pytest.raises(BagError) as err:
        list(r.messages(["/cam", "/camera/image_raw"]))
    text = str(err.value)
    assert "no topic /camera/image_raw in this bag" in text
    assert f"/cam ({IMAGE}), /cam/info ({INFO})" in text


@pytest.mark.parametrize("storage", ["directory", "mcap"])
def test_a_truncated_bag_yields_the_good_part_and_warns_where_it_broke(
        tmp_path: Path, storage: str) -> None:
    bag = tmp_path / ("cut" if storage == "directory" else "cut.mcap")
    write_bag(bag, list(range(40)), chunk_size=600, storage=storage)
    mcap = bag / "cut_0.mcap" if storage == "directory" else bag
    size = mcap.stat().st_size
    with open(mcap, "r+b") as fh:
        fh.truncate(size // 2)
    with BagReader(bag) as r:
        got = frames_read(r, on_damage="stop")
        assert 5 < len(got) < 40 and got == list(range(len(got)))
        assert len(r.warnings) == 1
        assert f"{mcap}: truncated at byte offset " in r.warnings[0]
    with BagReader(bag) as r, pytest.raises(BagError, match="truncated at byte offset"):
        list(r.messages("/cam"))  # the default: the break is an error, after the good part


# -- property-based: random damage to a small valid bag --------------------------------------


def _small_bags() -> list[bytes]:
    """Three small valid bags (zstd, lz4 and uncompressed chunks) as bytes."""
    out = []
    with tempfile.TemporaryDirectory() as root:
        for compression in ("zstd", "lz4", "none"):
            path = Path(root) / f"{compression}.mcap"
            write_bag(path, [0, 3, 1, 2, 4, 5], compression=compression, chunk_size=300)
            out.append(path.read_bytes())
    return out


SMALL_BAGS = _small_bags()
LENGTHS = [b"\xff" * 8, (2**40).to_bytes(8, "little"), (2**62).to_bytes(8, "little"), bytes(8)]


@st.composite
def damaged_bags(draw: st.DrawFn) -> bytes:
    data = bytearray(draw(st.sampled_from(SMALL_BAGS)))
    for _ in range(draw(st.integers(1, 3))):
        action = draw(st.sampled_from(["flip", "cut", "insert", "length"]))
        where = draw(st.integers(0, len(data) - 1)) if data else 0
        if action == "flip" and data:
            data[where] ^= draw(st.integers(1, 255))
        elif action == "cut":
            del data[where:]
        elif action == "insert":
            data[where:where] = draw(st.binary(min_size=1, max_size=9))
        elif action == "length" and len(data) > where + 8:  # a huge declared length
            data[where : where + 8] = draw(st.sampled_from(LENGTHS))
    return bytes(data)


@settings(derandomize=True, max_examples=250, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(damaged_bags())
def test_fuzzed_damaged_bags_yield_messages_or_raise_bag_error(tmp_path: Path,
                                                               data: bytes) -> None:
    bag = tmp_path / "damaged.mcap"
    bag.write_bytes(data)
    try:
        with BagReader(bag) as r:
            assert isinstance(r.topics, dict)
            assert r.message_count is None or r.message_count >= 0
            for m in r.messages(on_damage="stop"):
                with contextlib.suppress(BagError):
                    m.decode()
            for _ in r.messages():
                pass
    except BagError as err:
        assert str(bag) in str(err) or "cannot decode" in str(err)
