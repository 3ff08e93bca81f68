"""Writing rosbag2 recordings in the MCAP storage format, as `ros2 bag record -s mcap` does.

A "directory" bag is ``<dir>/metadata.yaml`` (rosbag2 bag file information, version 9)
plus ``<dir>/<dir name>_0.mcap``; an "mcap" bag is the bare .mcap file. Inside the MCAP
file, as rosbag2 writes it: profile ``ros2``; one Schema per message type whose data is
the complete ``ros2msg`` definition; one Channel per topic with ``cdr`` encoding and the
``offered_qos_profiles`` / ``topic_type_hash`` metadata; a ``rosbag2`` Metadata record
holding the serialized bag information; chunked, indexed, with a summary.
"""

from __future__ import annotations

import array
import contextlib
import os
import shutil
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import Any, Literal

import numpy as np
import yaml
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from mcap_ros2._dynamic import serialize_dynamic

from artcal_ros.bag.msgdefs import (
    MessageDefinition,
    message_definition,
    normalize_type_name,
)
from artcal_ros.core.errors import BagError

METADATA_VERSION = 9
ROS_DISTRO = "kilted"
# rmw's "infinite" duration, as rosbag2 writes it in QoS profiles.
_INFINITE = {"sec": 9223372036, "nsec": 854775807}
DEFAULT_QOS: dict[str, Any] = {
    "history": "keep_last",
    "depth": 10,
    "reliability": "reliable",
    "durability": "volatile",
    "deadline": dict(_INFINITE),
    "lifespan": dict(_INFINITE),
    "liveliness": "automatic",
    "liveliness_lease_duration": dict(_INFINITE),
    "avoid_ros_namespace_conventions": False,
}
_COMPRESSION = {
    "zstd": CompressionType.ZSTD,
    "lz4": CompressionType.LZ4,
    "none": CompressionType.NONE,
}


class _Fields:
    """Read-only view of a message given as a dict or an object, in the shapes the CDR
    encoder takes: numpy arrays, bytearrays and memoryviews become bytes or lists, numpy
    scalars Python numbers, and nested messages views of their own."""

    __slots__ = ("_obj",)

    def __init__(self, obj: Any) -> None:
        self._obj = obj

    def __getitem__(self, name: str) -> Any:
        if isinstance(self._obj, dict):
            value = self._obj[name]  # KeyError: the encoder then uses the default
        else:
            try:
                value = getattr(self._obj, name)
            except AttributeError:
                raise KeyError(name) from None
        return _plain(value)


def _plain(value: Any) -> Any:
    if isinstance(value, str | bytes | bool | int | float) or value is None:
        return value
    if isinstance(value, np.ndarray):
        return value.tobytes() if value.dtype == np.uint8 else value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, bytearray | memoryview):
        return bytes(value)
    if isinstance(value, array.array):
        return value
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    return _Fields(value)


class BagWriter:
    """Writes messages to a new rosbag2 MCAP recording.

    Use as a context manager; the file is finished (summary, metadata.yaml) on exit,
    also when the block raised, so what was written stays readable.

    Args:
        path: the bag directory to create (storage="directory") or the .mcap file
            (storage="mcap").
        storage: "directory" (rosbag2 directory) or "mcap" (bare .mcap file); by default
            "mcap" when ``path`` ends in .mcap, else "directory".
        compression: chunk compression, "zstd" (rosbag2's default), "lz4" or "none".
        chunk_size: bytes of messages per chunk before it is compressed and written; a
            reader holds about one chunk in memory.
        overwrite: replace an existing bag at ``path`` (only a rosbag2 directory with a
            metadata.yaml, or a .mcap file, is ever removed).

    Raises:
        BagError: ``path`` exists (and overwrite is false) or cannot be created.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        storage: Literal["directory", "mcap"] | None = None,
        *,
        compression: Literal["zstd", "lz4", "none"] = "zstd",
        chunk_size: int = 768 * 1024,
        overwrite: bool = False,
    ) -> None:
        if storage is None:
            storage = "mcap" if str(path).endswith(".mcap") else "directory"
        if storage not in ("directory", "mcap"):
            raise BagError(f"storage must be 'directory' or 'mcap', not {storage!r}")
        if compression not in _COMPRESSION:
            raise BagError(
                f"compression must be one of {sorted(_COMPRESSION)}, not {compression!r}"
            )
        self.path = Path(path).expanduser()
        self.storage: str = storage
        if self.path.exists() or self.path.is_symlink():
            if not overwrite:
                raise BagError(
                    f"{self.path} exists already; choose a new path or pass overwrite=True"
                )
            _remove_bag(self.path)
        if storage == "directory":
            try:
                self.path.mkdir(parents=True)
            except OSError as err:
                raise BagError(f"{self.path}: cannot create the bag directory: {err}") from err
            self.mcap_path = self.path / f"{self.path.name}_0.mcap"
        else:
            self.mcap_path = self.path
        try:
            self._fh = open(self.mcap_path, "xb")  # noqa: SIM115 - closed by close()
        except OSError as err:
            raise BagError(f"{self.mcap_path}: cannot create: {err}") from err
        self._mcap = McapWriter(
            self._fh, chunk_size=chunk_size, compression=_COMPRESSION[compression]
        )
        self._mcap.start(profile="ros2", library="artcal_ros")
        self._definitions: dict[str, MessageDefinition] = {}
        self._schema_ids: dict[str, int] = {}
        self._encoders: dict[str, Callable[[Any], bytes]] = {}
        self._channels: dict[str, tuple[int, str]] = {}  # topic -> (channel id, msgtype)
        self._counts: dict[str, int] = {}
        self._start_ns: int | None = None
        self._end_ns: int | None = None
        self._closed = False

    # -- types -----------------------------------------------------------------------------

    def add_type(self, msgtype: str, definition: str, type_hash: str = "") -> None:
        """Make a message type that is not built in writable.

        Args:
            msgtype: ``pkg/msg/Type``.
            definition: complete ``ros2msg`` definition (the type, then each dependency
                after a line of 80 ``=`` and ``MSG: pkg/msg/Dep``).
            type_hash: RIHS01 hash for metadata.yaml, or "" if unknown.
        """
        name = normalize_type_name(msgtype)
        self._definitions[name] = MessageDefinition(name, definition, type_hash)

    def _definition(self, msgtype: str) -> MessageDefinition:
        if msgtype not in self._definitions:
            try:
                self._definitions[msgtype] = message_definition(msgtype)
            except KeyError as err:
                raise BagError(
                    f"cannot write {msgtype}: {err.args[0]}; register it with "
                    "BagWriter.add_type(msgtype, definition)"
                ) from None
        return self._definitions[msgtype]

    def _channel(self, topic: str, msgtype: str) -> int:
        if topic in self._channels:
            channel_id, known = self._channels[topic]
            if known != msgtype:
                raise BagError(
                    f"topic {topic} already carries {known}; cannot also write {msgtype} on it"
                )
            return channel_id
        definition = self._definition(msgtype)
        if msgtype not in self._schema_ids:
            self._schema_ids[msgtype] = self._mcap.register_schema(
                msgtype, "ros2msg", definition.text.encode()
            )
        channel_id = self._mcap.register_channel(
            topic,
            "cdr",
            self._schema_ids[msgtype],
            metadata={
                "offered_qos_profiles": yaml.safe_dump([DEFAULT_QOS], sort_keys=False).strip(),
                "topic_type_hash": definition.type_hash,
            },
        )
        self._channels[topic] = (channel_id, msgtype)
        self._counts[topic] = 0
        return channel_id

    def _encode(self, msgtype: str, topic: str, msg: Any) -> bytes:
        if isinstance(msg, bytes | bytearray | memoryview):
            return bytes(msg)  # already CDR (e.g. copied from another bag)
        encoder = self._encoders.get(msgtype)
        if encoder is None:
            definition = self._definition(msgtype)
            try:
                encoder = serialize_dynamic(msgtype, definition.text)[msgtype]
            except Exception as err:
                raise BagError(f"cannot parse the definition of {msgtype}: {err}") from err
            self._encoders[msgtype] = encoder
        try:
            return encoder(_Fields(msg))
        except Exception as err:  # a field of the wrong type or shape
            raise BagError(
                f"cannot encode a {msgtype} message for topic {topic}: {err}"
            ) from err

    # -- writing ---------------------------------------------------------------------------

    def write(
        self,
        topic: str,
        msgtype: str,
        timestamp_ns: int,
        msg: Any,
        *,
        publish_time_ns: int | None = None,
    ) -> None:
        """Append one message.

        Args:
            topic: e.g. ``/camera/image_raw``.
            msgtype: e.g. ``sensor_msgs/msg/Image``.
            timestamp_ns: receive time, nanoseconds since the epoch (the bag's log time).
            msg: a dict or object with the message's fields (missing fields take their
                defaults), or already-serialized CDR bytes.
            publish_time_ns: publish time; defaults to ``timestamp_ns``.
        """
        if self._closed:
            raise BagError(f"{self.path}: the bag is closed")
        name = normalize_type_name(msgtype)
        timestamp_ns = int(timestamp_ns)
        if timestamp_ns < 0:
            raise BagError(f"timestamp_ns must be >= 0, got {timestamp_ns}")
        channel_id = self._channel(topic, name)
        data = self._encode(name, topic, msg)
        self._mcap.add_message(
            channel_id=channel_id,
            log_time=timestamp_ns,
            publish_time=timestamp_ns if publish_time_ns is None else int(publish_time_ns),
            sequence=self._counts[topic],
            data=data,
        )
        self._counts[topic] += 1
        if self._start_ns is None or timestamp_ns < self._start_ns:
            self._start_ns = timestamp_ns
        self._end_ns = max(timestamp_ns, self._end_ns or 0)

    def bag_information(self) -> dict[str, Any]:
        """The ``rosbag2_bagfile_information`` mapping for what has been written so far."""
        start = self._start_ns or 0
        duration = (self._end_ns or 0) - start
        count = sum(self._counts.values())
        file_name = self.mcap_path.name
        return {
            "version": METADATA_VERSION,
            "storage_identifier": "mcap",
            "duration": {"nanoseconds": duration},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": count,
            "topics_with_message_count": [
                {
                    "topic_metadata": {
                        "name": topic,
                        "type": msgtype,
                        "serialization_format": "cdr",
                        "offered_qos_profiles": [dict(DEFAULT_QOS)],
                        "type_description_hash": self._definitions[msgtype].type_hash,
                    },
                    "message_count": self._counts[topic],
                }
                for topic, (_cid, msgtype) in self._channels.items()
            ],
            "compression_format": "",
            "compression_mode": "",
            "relative_file_paths": [file_name],
            "files": [
                {
                    "path": file_name,
                    "starting_time": {"nanoseconds_since_epoch": start},
                    "duration": {"nanoseconds": duration},
                    "message_count": count,
                }
            ],
            "custom_data": None,
            "ros_distro": ROS_DISTRO,
        }

    def close(self) -> None:
        """Finish the MCAP file and, for a directory bag, write metadata.yaml (atomically)."""
        if self._closed:
            return
        self._closed = True
        info = self.bag_information()
        serialized = yaml.safe_dump(info, sort_keys=False)
        try:
            self._mcap.add_metadata(
                "rosbag2", {"serialized_metadata": serialized, "ROS_DISTRO": ROS_DISTRO}
            )
            self._mcap.finish()
        finally:
            self._fh.close()
        if self.storage == "directory":
            meta = self.path / "metadata.yaml"
            tmp = meta.with_suffix(".yaml.tmp")
            tmp.write_text(
                yaml.safe_dump({"rosbag2_bagfile_information": info}, sort_keys=False),
                encoding="utf-8",
            )
            tmp.replace(meta)

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def _remove_bag(path: Path) -> None:
    """Remove an existing bag, refusing anything that does not look like one."""
    if path.is_dir() and not path.is_symlink():
        entries = {p.name for p in path.iterdir()}
        if "metadata.yaml" not in entries and entries:
            raise BagError(
                f"{path} exists and is not a rosbag2 directory (no metadata.yaml); "
                "not removing it"
            )
        shutil.rmtree(path)
    elif path.suffix == ".mcap" or path.is_symlink():
        with contextlib.suppress(FileNotFoundError):
            path.unlink()
    else:
        raise BagError(f"{path} exists and is not a .mcap file; not removing it")
