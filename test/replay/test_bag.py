"""rosbag2 MCAP reading and writing: round trips, an independent implementation both ways,
damaged files, and lazy iteration."""

from __future__ import annotations

import tracemalloc
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import breakup_chunk

from artcal_ros.bag import BagMessage, BagReader, BagWriter
from artcal_ros.bag.msgdefs import TYPE_HASHES, message_definition
from artcal_ros.core.errors import BagError

IMAGE = "sensor_msgs/msg/Image"
INFO = "sensor_msgs/msg/CameraInfo"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
T0 = 1_700_000_000_000_000_000  # ns since the epoch


def image_fields(img: np.ndarray, encoding: str, stamp_ns: int) -> dict[str, Any]:
    h, w = img.shape[:2]
    return {
        "header": {
            "stamp": {"sec": stamp_ns // 10**9, "nanosec": stamp_ns % 10**9},
            "frame_id": "camera_optical",
        },
        "height": h,
        "width": w,
        "encoding": encoding,
        "is_bigendian": 0,
        "step": img.strides[0],
        "data": np.ascontiguousarray(img),
    }


def info_fields(stamp_ns: int) -> dict[str, Any]:
    return {
        "header": {"stamp": {"sec": stamp_ns // 10**9, "nanosec": stamp_ns % 10**9},
                   "frame_id": "camera_optical"},
        "height": 48,
        "width": 64,
        "distortion_model": "plumb_bob",
        "d": np.array([-0.25, 0.08, 0.001, -0.0005, 0.0]),
        "k": np.array([[60.0, 0, 31.5], [0, 61.0, 23.5], [0, 0, 1]]).ravel(),
        "r": np.eye(3).ravel(),
        "p": np.array([[60.0, 0, 31.5, 0], [0, 61.0, 23.5, 0], [0, 0, 1, 0]]).ravel(),
        "binning_x": 1,
        "binning_y": 2,
        "roi": {"x_offset": 3, "y_offset": 4, "height": 5, "width": 6, "do_rectify": True},
    }


def write_sample(path: Path, storage: str, n: int = 6) -> list[tuple[str, int, Any]]:
    """A small mixed bag; returns what was written, (topic, timestamp, source) in order."""
    rng = np.random.default_rng(7)
    written: list[tuple[str, int, Any]] = []
    with BagWriter(path, storage=storage) as w:  # type: ignore[arg-type]
        for i in range(n):
            t = T0 + i * 33_333_333
            mono = rng.integers(0, 256, (48, 64), dtype=np.uint8)
            colour = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
            w.write("/camera/image_raw", IMAGE, t, image_fields(mono, "mono8", t))
            w.write("/camera/color", IMAGE, t + 1, image_fields(colour, "bgr8", t))
            written += [("/camera/image_raw", t, mono), ("/camera/color", t + 1, colour)]
            if i % 3 == 0:
                w.write("/camera/camera_info", INFO, t + 2, info_fields(t))
                written.append(("/camera/camera_info", t + 2, None))
        w.write("/camera/image_raw/compressed", COMPRESSED, T0 + n * 10**8,
                {"header": {"frame_id": "x"}, "format": "png", "data": b"\x89PNG fake"})
        written.append(("/camera/image_raw/compressed", T0 + n * 10**8, b"\x89PNG fake"))
    return written


def check_image(msg: Any, expected: np.ndarray, stamp_ns: int) -> None:
    assert msg.height == expected.shape[0] and msg.width == expected.shape[1]
    assert msg.step == expected.strides[0]
    assert msg.header.stamp.sec == stamp_ns // 10**9
    assert msg.header.stamp.nanosec == stamp_ns % 10**9
    assert msg.header.frame_id == "camera_optical"
    got = np.frombuffer(bytes(msg.data), np.uint8).reshape(expected.shape)
    np.testing.assert_array_equal(got, expected)


def check_round_trip(path: Path, written: list[tuple[str, int, Any]]) -> None:
    with BagReader(path) as r:
        assert r.topics == {
            "/camera/image_raw": IMAGE,
            "/camera/color": IMAGE,
            "/camera/camera_info": INFO,
            "/camera/image_raw/compressed": COMPRESSED,
        }
        assert r.message_count == len(written)
        got = list(r.messages())
    assert [(m.topic, m.log_time_ns) for m in got] == [(t, ts) for t, ts, _ in written]
    for m, (topic, ts, src) in zip(got, written, strict=True):
        assert m.publish_time_ns == ts
        msg = m.decode()
        if m.msgtype == IMAGE:
            check_image(msg, src, ts - (topic == "/camera/color"))
            assert msg.encoding == ("bgr8" if src.ndim == 3 else "mono8")
        elif m.msgtype == INFO:
            ref = info_fields(ts - 2)
            assert msg.distortion_model == "plumb_bob"
            np.testing.assert_array_equal(msg.d, ref["d"])
            np.testing.assert_array_equal(msg.k, ref["k"])
            np.testing.assert_array_equal(msg.p, ref["p"])
            assert (msg.binning_y, msg.roi.width, msg.roi.do_rectify) == (2, 6, True)
        else:
            assert m.msgtype == COMPRESSED
            assert (msg.format, bytes(msg.data)) == ("png", src)


def test_round_trip_directory(tmp_path: Path) -> None:
    bag = tmp_path / "run1"
    written = write_sample(bag, "directory")
    check_round_trip(bag, written)
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["version"] == 9 and info["storage_identifier"] == "mcap"
    assert info["relative_file_paths"] == ["run1_0.mcap"]
    assert (bag / "run1_0.mcap").is_file()
    assert info["message_count"] == len(written)
    assert info["starting_time"]["nanoseconds_since_epoch"] == T0
    assert info["duration"]["nanoseconds"] == written[-1][1] - T0
    counts = {t["topic_metadata"]["name"]: t["message_count"]
              for t in info["topics_with_message_count"]}
    assert counts == {"/camera/image_raw": 6, "/camera/color": 6, "/camera/camera_info": 2,
                      "/camera/image_raw/compressed": 1}
    for entry in info["topics_with_message_count"]:
        tm = entry["topic_metadata"]
        assert tm["serialization_format"] == "cdr"
        assert tm["type_description_hash"] == TYPE_HASHES[tm["type"]]
        assert tm["offered_qos_profiles"][0]["reliability"] == "reliable"


def test_round_trip_bare_mcap(tmp_path: Path) -> None:
    bag = tmp_path / "run1.mcap"
    written = write_sample(bag, "mcap")
    assert not (tmp_path / "metadata.yaml").exists()
    check_round_trip(bag, written)


def test_unchunked_file_without_summary(tmp_path: Path) -> None:
    """Another writer's layout: messages outside chunks and no index, read linearly."""
    from mcap.writer import IndexType
    from mcap.writer import Writer as McapWriter
    from mcap_ros2._dynamic import serialize_dynamic

    definition = message_definition(IMAGE).text
    encode = serialize_dynamic(IMAGE, definition)[IMAGE]
    path = tmp_path / "plain.mcap"
    frames = [bytes([i]) * 12 for i in range(5)]
    with open(path, "wb") as fh:
        w = McapWriter(fh, use_chunking=False, index_types=IndexType.NONE, use_statistics=False,
                       repeat_channels=False, repeat_schemas=False, use_summary_offsets=False)
        w.start(profile="ros2")
        sid = w.register_schema(IMAGE, "ros2msg", definition.encode())
        cid = w.register_channel("/image", "cdr", sid)
        for i, f in enumerate(frames):
            w.add_message(cid, log_time=T0 + i, publish_time=T0 + i,
                          data=encode({"height": 3, "width": 4, "step": 4, "data": f}))
        w.finish()
    with BagReader(path) as r:
        assert r.topics == {"/image": IMAGE} and r.message_count is None
        got = [m.decode() for m in r]
    assert [bytes(m.data) for m in got] == frames


def test_storage_follows_the_suffix_by_default(tmp_path: Path) -> None:
    with BagWriter(tmp_path / "a.mcap") as w, BagWriter(tmp_path / "b") as v:
        w.write("/i", IMAGE, T0, {})
        v.write("/i", IMAGE, T0, {})
    assert (tmp_path / "a.mcap").is_file() and (tmp_path / "b" / "metadata.yaml").is_file()


def test_messages_come_in_log_time_order_across_chunks(tmp_path: Path) -> None:
    """Chunks whose time ranges overlap are merged, as `ros2 bag play` orders them."""
    rng = np.random.default_rng(2)
    stamps = [int(t) for t in T0 + rng.permutation(60) * 1000]
    bag = tmp_path / "shuffled.mcap"
    with BagWriter(bag, chunk_size=4096, compression="none") as w:
        for i, t in enumerate(stamps):
            w.write("/image", IMAGE, t, {"height": 1, "width": 1, "step": 1,
                                         "encoding": "mono8", "data": bytes([i]) * 3000})
    with BagReader(bag) as r:
        got = list(r)
    assert [m.log_time_ns for m in got] == sorted(stamps)
    # each message is still the one written at that time
    assert all(stamps[m.decode().data[0]] == m.log_time_ns for m in got)


def test_topic_filter_and_raw_bytes(tmp_path: Path) -> None:
    bag = tmp_path / "b"
    written = write_sample(bag, "directory")
    with BagReader(bag) as r:
        infos = list(r.messages(topics="/camera/camera_info"))
        colour = list(r.messages(topics=["/camera/color"]))
    assert [m.log_time_ns for m in infos] == [ts for t, ts, _ in written
                                              if t == "/camera/camera_info"]
    assert len(colour) == 6 and all(m.topic == "/camera/color" for m in colour)
    # Raw CDR bytes copied into a new bag come back identical and decodable.
    copy = tmp_path / "copy.mcap"
    with BagWriter(copy, storage="mcap") as w:
        for m in colour:
            w.write(m.topic, m.msgtype, m.log_time_ns, m.data)
    with BagReader(copy) as r:
        again = list(r)
    assert [m.data for m in again] == [m.data for m in colour]
    check_image(again[0].decode(), written[1][2], written[1][1] - 1)


def test_rclpy_message_objects_are_written(tmp_path: Path) -> None:
    sensor_msgs = pytest.importorskip("sensor_msgs.msg")
    img = sensor_msgs.Image()
    img.header.frame_id = "camera_optical"
    img.header.stamp.sec, img.header.stamp.nanosec = 12, 345
    img.height, img.width, img.encoding, img.step = 2, 3, "mono8", 3
    img.data = bytes(range(6))
    info = sensor_msgs.CameraInfo()
    info.k = [1.0, 0.0, 2.0, 0.0, 3.0, 4.0, 0.0, 0.0, 1.0]
    info.d = [0.1, -0.2, 0.0, 0.0, 0.05]
    info.distortion_model = "plumb_bob"
    with BagWriter(tmp_path / "r") as w:
        w.write("/image", IMAGE, T0, img)
        w.write("/info", INFO, T0 + 1, info)
    with BagReader(tmp_path / "r") as r:
        a, b = (m.decode() for m in r)
    assert (a.header.stamp.sec, a.header.stamp.nanosec, a.header.frame_id) == (
        12, 345, "camera_optical")
    assert bytes(a.data) == bytes(range(6)) and a.encoding == "mono8"
    assert list(b.k) == list(info.k) and list(b.d) == pytest.approx([0.1, -0.2, 0, 0, 0.05])


# -- an independent implementation (rosbags) -------------------------------------------------


def test_definitions_match_ros_interfaces() -> None:
    typesys = pytest.importorskip("rosbags.typesys")
    kilted = typesys.get_typestore(typesys.Stores.ROS2_KILTED)
    for msgtype in (IMAGE, INFO, COMPRESSED):
        text = message_definition(msgtype).text
        # Build a store from our text alone: same fields <=> same RIHS01 hash.
        store = typesys.get_typestore(typesys.Stores.EMPTY)
        store.register(typesys.get_types_from_msg(text, msgtype))
        assert store.hash_rihs01(msgtype) == kilted.hash_rihs01(msgtype) == TYPE_HASHES[msgtype]


def test_rosbags_reads_our_bag(tmp_path: Path) -> None:
    rosbag2 = pytest.importorskip("rosbags.rosbag2")
    typesys = pytest.importorskip("rosbags.typesys")
    store = typesys.get_typestore(typesys.Stores.ROS2_KILTED)
    bag = tmp_path / "ours"
    written = write_sample(bag, "directory")
    with rosbag2.Reader(bag) as r:
        assert {c.topic: c.msgtype for c in r.connections} == {
            "/camera/image_raw": IMAGE, "/camera/color": IMAGE,
            "/camera/camera_info": INFO, "/camera/image_raw/compressed": COMPRESSED}
        got = [(c.topic, ts, store.deserialize_cdr(raw, c.msgtype)) for c, ts, raw in r.messages()]
    assert [(t, ts) for t, ts, _ in got] == [(t, ts) for t, ts, _ in written]
    images = [(g, w) for g, w in zip(got, written, strict=True) if g[2].__msgtype__ == IMAGE]
    assert len(images) == 12
    for (topic, ts, msg), (_t, _ts, src) in images:
        check_image(msg, src, ts - (topic == "/camera/color"))
    info = next(m for t, _, m in got if t == "/camera/camera_info")
    np.testing.assert_array_equal(info.k, info_fields(T0)["k"])
    assert info.roi.do_rectify is True


@pytest.mark.parametrize("version", [8, 9])
def test_we_read_a_rosbags_bag(tmp_path: Path, version: int) -> None:
    rosbag2 = pytest.importorskip("rosbags.rosbag2")
    typesys = pytest.importorskip("rosbags.typesys")
    store = typesys.get_typestore(typesys.Stores.ROS2_KILTED)
    Image = store.types[IMAGE]
    Header = store.types["std_msgs/msg/Header"]
    Time = store.types["builtin_interfaces/msg/Time"]
    rng = np.random.default_rng(version)
    frames = [rng.integers(0, 256, (30, 40, 3), dtype=np.uint8) for _ in range(5)]
    bag = tmp_path / "theirs"
    raws = []
    with rosbag2.Writer(bag, version=version, storage_plugin=rosbag2.StoragePlugin.MCAP) as w:
        conn = w.add_connection("/cam/image", IMAGE, typestore=store)
        for i, frame in enumerate(frames):
            ts = T0 + i * 50_000_000
            msg = Image(
                header=Header(stamp=Time(sec=ts // 10**9, nanosec=ts % 10**9),
                              frame_id="camera_optical"),
                height=30, width=40, encoding="rgb8", is_bigendian=0, step=120,
                data=frame.reshape(-1),
            )
            raw = store.serialize_cdr(msg, IMAGE)
            raws.append(bytes(raw))
            w.write(conn, ts, raw)
    with BagReader(bag) as r:
        assert r.topics == {"/cam/image": IMAGE}
        assert r.message_count == 5
        got = list(r.messages())
    assert [m.data for m in got] == raws
    for i, (m, frame) in enumerate(zip(got, frames, strict=True)):
        ts = T0 + i * 50_000_000
        assert m.log_time_ns == ts and m.msgtype == IMAGE
        msg = m.decode()
        assert msg.encoding == "rgb8"
        check_image(msg, frame, ts)


# -- damaged and wrong inputs ----------------------------------------------------------------


def write_frames(path: Path, n: int, *, storage: str = "directory", shape=(120, 160),
                 chunk_size: int = 64 * 1024) -> list[np.ndarray]:
    rng = np.random.default_rng(1)
    frames = [rng.integers(0, 256, shape, dtype=np.uint8) for _ in range(n)]
    with BagWriter(path, storage=storage, chunk_size=chunk_size,  # type: ignore[arg-type]
                   compression="none") as w:
        for i, f in enumerate(frames):
            w.write("/image", IMAGE, T0 + i * 10**7, image_fields(f, "mono8", T0 + i * 10**7))
    return frames


def breakup_chunk_at(path: Path, offset: int) -> list[Message]:
    with open(path, "rb") as fh:
        fh.seek(offset + 9)
        chunk = Chunk.read(ReadDataStream(fh))
    return [r for r in breakup_chunk(chunk) if isinstance(r, Message)]


@pytest.mark.parametrize("storage", ["directory", "mcap"])
def test_truncated_bag_yields_what_precedes_the_cut(tmp_path: Path, storage: str) -> None:
    bag = tmp_path / ("cut" if storage == "directory" else "cut.mcap")
    frames = write_frames(bag, 40, storage=storage)
    mcap = bag / "cut_0.mcap" if storage == "directory" else bag
    cut = mcap.stat().st_size // 2
    with open(mcap, "rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    # the messages in the chunks that lie wholly before the cut (the writer's own index)
    expected = 0
    for ci in summary.chunk_indexes:
        if ci.chunk_start_offset + ci.chunk_length <= cut:
            expected += len(breakup_chunk_at(mcap, ci.chunk_start_offset))
    with open(mcap, "r+b") as fh:
        fh.truncate(cut)
    got: list[BagMessage] = []
    with BagReader(bag) as r, pytest.raises(BagError) as excinfo:
        for m in r.messages():
            got.append(m)
    text = str(excinfo.value)
    assert str(mcap) in text and "truncated at byte offset" in text
    assert f"after {len(got)} messages" in text
    assert len(got) == expected
    assert 15 <= expected < 40  # several 64 kB chunks of 19 kB frames before the cut
    for i, m in enumerate(got):
        check_image(m.decode(), frames[i], T0 + i * 10**7)


def test_corrupt_chunk_is_reported_with_its_offset(tmp_path: Path) -> None:
    bag = tmp_path / "bad.mcap"
    write_frames(bag, 20, storage="mcap")
    data = bytearray(bag.read_bytes())
    middle = len(data) // 2
    data[middle : middle + 64] = bytes(64)  # the footer stays intact: an indexed read
    bag.write_bytes(bytes(data))
    broken = r"bad\.mcap: chunk at byte offset \d+ \(after \d+ messages\)"
    with BagReader(bag) as r, pytest.raises(BagError, match=broken):
        for _ in r.messages():
            pass


def test_garbage_file(tmp_path: Path) -> None:
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(np.random.default_rng(0).integers(0, 256, 5000, dtype=np.uint8).tobytes())
    with pytest.raises(BagError, match=r"junk\.mcap: not an MCAP file"):
        BagReader(junk)
    # MCAP magic followed by garbage: no summary, the linear read breaks at once.
    fake = tmp_path / "fake.mcap"
    fake.write_bytes(b"\x89MCAP0\r\n" + b"\x06" + (10**9).to_bytes(8, "little") + b"x" * 100)
    with BagReader(fake) as r, pytest.raises(BagError, match=r"fake\.mcap: truncated at byte "
                                                            r"offset 8 \(after 0 messages\)"):
        list(r.messages())


def test_wrong_paths(tmp_path: Path) -> None:
    with pytest.raises(BagError, match="no such bag"):
        BagReader(tmp_path / "nothing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(BagError, match=r"neither a metadata\.yaml nor any \.mcap"):
        BagReader(tmp_path / "empty")
    old = tmp_path / "old"
    old.mkdir()
    (old / "old_0.db3").write_bytes(b"SQLite format 3\x00" + bytes(100))
    with pytest.raises(BagError, match="sqlite3 storage plugin; artcal reads MCAP bags only"):
        BagReader(old)
    with pytest.raises(BagError, match="sqlite3"):
        BagReader(old / "old_0.db3")
    (old / "metadata.yaml").write_text(
        "rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: sqlite3\n"
        "  relative_file_paths: [old_0.db3]\n")
    with pytest.raises(BagError, match="sqlite3"):
        BagReader(old)
    (old / "metadata.yaml").write_text(
        "rosbag2_bagfile_information:\n  storage_identifier: mcap\n"
        "  relative_file_paths: [gone_0.mcap]\n")
    with pytest.raises(BagError, match=r"lists files that do not exist: .*gone_0\.mcap"):
        BagReader(old)


def test_directory_without_metadata_is_read_from_its_mcap(tmp_path: Path) -> None:
    bag = tmp_path / "killed"
    frames = write_frames(bag, 5)
    (bag / "metadata.yaml").unlink()
    with BagReader(bag) as r:
        assert r.topics == {"/image": IMAGE} and r.message_count == 5
        got = [m.decode() for m in r]
    for i, m in enumerate(got):
        check_image(m, frames[i], T0 + i * 10**7)


def test_writer_refuses_bad_input(tmp_path: Path) -> None:
    bag = tmp_path / "w"
    write_frames(bag, 1)
    with pytest.raises(BagError, match="exists already"):
        BagWriter(bag)
    with BagWriter(bag, overwrite=True) as w:  # replaces the old bag
        with pytest.raises(BagError, match="no built-in message definition for 'pkg/msg/Nope'"):
            w.write("/x", "pkg/msg/Nope", T0, {})
        w.write("/image", IMAGE, T0, {"height": 1, "width": 1, "data": b"\x05"})
        with pytest.raises(BagError, match="/image already carries sensor_msgs/msg/Image"):
            w.write("/image", INFO, T0, {})
        with pytest.raises(BagError, match="cannot encode a sensor_msgs/msg/Image"):
            w.write("/image", IMAGE, T0, {"height": "tall"})
    with BagReader(bag) as r:
        assert r.message_count == 1 and next(iter(r)).decode().data == b"\x05"
    not_a_bag = tmp_path / "docs"
    not_a_bag.mkdir()
    (not_a_bag / "notes.txt").write_text("keep me")
    with pytest.raises(BagError, match="not a rosbag2 directory"):
        BagWriter(not_a_bag, overwrite=True)
    assert (not_a_bag / "notes.txt").exists()


def test_an_exception_inside_the_block_still_leaves_a_readable_bag(tmp_path: Path) -> None:
    bag = tmp_path / "crash"
    with pytest.raises(RuntimeError), BagWriter(bag) as w:
        w.write("/image", IMAGE, T0, {"height": 1, "width": 1, "data": b"\x01"})
        raise RuntimeError("camera unplugged")
    with BagReader(bag) as r:
        assert r.message_count == 1 and len(list(r)) == 1


def test_iteration_is_lazy(tmp_path: Path) -> None:
    """200 frames (15 MB of pixels) are read holding about one chunk at a time."""
    bag = tmp_path / "long"
    frame_bytes = 240 * 320
    write_frames(bag, 200, shape=(240, 320), chunk_size=256 * 1024)
    total = 200 * frame_bytes
    with BagReader(bag) as r:
        it = r.messages()
        tracemalloc.start()
        first = next(it)
        after_first = tracemalloc.get_traced_memory()[0]
        count = 1
        for m in it:
            count += 1
            assert len(m.data) > frame_bytes
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    assert count == 200 and first.log_time_ns == T0
    assert after_first < 2 * 1024 * 1024  # one chunk read, not the bag
    print(f"after first {after_first} B, peak {peak} B, bag {total} B")
    assert peak < 2 * 1024 * 1024 < total / 5  # bounded by the chunk size, not the bag


def test_images_through_a_bag(tmp_path: Path) -> None:
    """numpy -> numpy_to_image -> bag -> decode -> image_to_numpy gives back the pixels."""
    from artcal_ros.core.images import image_to_numpy, numpy_to_image

    rng = np.random.default_rng(4)
    images = {
        "mono16": rng.integers(0, 65536, (24, 32), dtype=np.uint16),
        "rgb8": rng.integers(0, 256, (24, 32, 3), dtype=np.uint8),
        "mono8": rng.integers(0, 256, (24, 32), dtype=np.uint8),
    }
    with BagWriter(tmp_path / "px") as w:
        for i, (encoding, img) in enumerate(images.items()):
            w.write(f"/{encoding}", IMAGE, T0 + i, numpy_to_image(img, encoding, T0 + i))
    with BagReader(tmp_path / "px") as r:
        for m in r:
            np.testing.assert_array_equal(image_to_numpy(m.decode()), images[m.topic[1:]])
