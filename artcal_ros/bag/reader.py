"""rosbag2 recordings in the MCAP storage format: reading and writing, without rclpy.

A bag is either a rosbag2 directory (``metadata.yaml`` plus one or more ``.mcap`` files,
as ``ros2 bag record -s mcap`` writes it) or a bare ``.mcap`` file::

    from artcal_ros.bag import BagReader, BagWriter

    with BagWriter("bags/run1") as w:              # or BagWriter("run1.mcap", storage="mcap")
        w.write("/camera/image_raw", "sensor_msgs/msg/Image", stamp_ns, fields)

    with BagReader("bags/run1") as r:
        print(r.topics, r.message_count)
        for m in r.messages(topics=["/camera/image_raw"]):   # lazy, log-time order
            image = m.decode()                               # attribute access: image.width
            republish(m.data)                                # the raw CDR bytes

Every problem (a missing path, a directory that is not a bag, a bag in sqlite3 storage,
a truncated or corrupt file) raises BagError naming the file and, for damaged files, the
byte offset where reading broke. Messages before a break are yielded first.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Collection, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any

import yaml
from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory

from artcal_ros.bag.mcap_file import SQLITE_MAGIC, McapFile
from artcal_ros.core.errors import BagError

__all__ = ["BagMessage", "BagReader"]


@dataclass(frozen=True)
class BagMessage:
    """One recorded message.

    Attributes:
        topic: the topic it was recorded on.
        msgtype: e.g. ``sensor_msgs/msg/Image``.
        log_time_ns: receive time, nanoseconds since the epoch.
        publish_time_ns: publish time, nanoseconds since the epoch.
        data: the serialized message (CDR), ready to republish.
    """

    topic: str
    msgtype: str
    log_time_ns: int
    publish_time_ns: int
    data: bytes
    _decoder: Callable[[bytes], Any] = field(repr=False, compare=False)

    def decode(self) -> Any:
        """The message as an object with attribute access (``msg.header.stamp.sec``).

        Raises:
            BagError: the bytes do not match the recorded message definition.
        """
        try:
            return self._decoder(self.data)
        except BagError:
            raise
        except Exception as err:
            raise BagError(
                f"cannot decode the {self.msgtype} message on {self.topic} at log time "
                f"{self.log_time_ns} ns: {type(err).__name__}: {err}"
            ) from err


class _Decoders:
    """CDR decoders generated from each file's schemas, built on first use."""

    def __init__(self) -> None:
        self._cache: dict[tuple[int, int], Callable[[bytes], Any]] = {}

    def get(self, file_index: int, path: Path, schema: Schema | None, encoding: str) -> Any:
        key = (file_index, schema.id if schema is not None else 0)
        decoder = self._cache.get(key)
        if decoder is None:
            decoder = self._make(path, schema, encoding)
            self._cache[key] = decoder
        return decoder

    def _make(self, path: Path, schema: Schema | None, encoding: str) -> Callable[[bytes], Any]:
        def failing(reason: str) -> Callable[[bytes], Any]:
            def decode(_data: bytes) -> Any:
                raise BagError(f"{path}: cannot decode: {reason}")

            return decode

        if schema is None:
            return failing("the channel has no schema (message definition)")
        if encoding != "cdr" or schema.encoding != "ros2msg":
            return failing(
                f"{schema.name} is stored as {encoding!r} with a {schema.encoding!r} schema; "
                "only cdr messages with ros2msg definitions can be decoded"
            )
        # Each file gets its own factory: schema ids are only unique within one file.
        factory = DecoderFactory()
        try:
            decoder = factory.decoder_for(encoding, schema)
        except Exception as err:
            return failing(f"the message definition of {schema.name} does not parse ({err})")
        if decoder is None:
            return failing(f"no decoder for {schema.name}")
        return decoder


class BagReader:
    """Reads a rosbag2 MCAP directory or a bare .mcap file.

    Args:
        path: a rosbag2 directory (metadata.yaml + .mcap files) or an .mcap file.

    Raises:
        BagError: the path does not exist, is not an MCAP bag, or cannot be opened.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path).expanduser()
        self.metadata: dict[str, Any] | None = None
        self._files: list[McapFile] = []
        self._decoders = _Decoders()
        try:
            for file_path in self._file_paths():
                self._files.append(McapFile(file_path))
        except BaseException:
            self.close()
            raise

    # -- locating the files ----------------------------------------------------------------

    def _file_paths(self) -> list[Path]:
        p = self.path
        if not p.exists():
            raise BagError(
                f"{p}: no such bag (expected a rosbag2 directory with metadata.yaml, "
                "or an .mcap file)"
            )
        if p.is_file():
            if p.suffix == ".db3" or _starts_with(p, SQLITE_MAGIC):
                raise _sqlite_error(p)
            return [p]
        meta_path = p / "metadata.yaml"
        if meta_path.is_file():
            self.metadata = _read_metadata(meta_path)
            names = self.metadata.get("relative_file_paths") or []
            paths = [p / str(name) for name in names]
            missing = [str(q) for q in paths if not q.is_file()]
            if missing:
                raise BagError(
                    f"{meta_path} lists files that do not exist: {', '.join(missing)}"
                )
            if not paths:
                raise BagError(f"{meta_path} lists no storage files (relative_file_paths)")
            return paths
        # No metadata.yaml (e.g. a recording that was killed): read the MCAP files alone.
        paths = sorted(p.glob("*.mcap"))
        if paths:
            return paths
        if list(p.glob("*.db3")):
            raise _sqlite_error(p)
        raise BagError(
            f"{p}: not a bag: the directory has neither a metadata.yaml nor any .mcap file"
        )

    # -- what is in the bag ----------------------------------------------------------------

    @property
    def files(self) -> list[Path]:
        """The .mcap files, in reading order."""
        return [f.path for f in self._files]

    @property
    def topics(self) -> dict[str, str]:
        """``{topic: msgtype}`` for every recorded topic."""
        if self.metadata is not None:
            out: dict[str, str] = {}
            for entry in self.metadata.get("topics_with_message_count") or []:
                tm = entry.get("topic_metadata") or {}
                if "name" in tm and "type" in tm:
                    out[str(tm["name"])] = str(tm["type"])
            if out:
                return out
        out = {}
        for f in self._files:
            for channel, schema in f.channels().values():
                out[channel.topic] = schema.name if schema is not None else ""
        return out

    @property
    def message_count(self) -> int | None:
        """Number of messages, from metadata.yaml or the MCAP statistics; None if unknown."""
        if self.metadata is not None and "message_count" in self.metadata:
            return int(self.metadata["message_count"])
        counts = [f.message_count() for f in self._files]
        if any(c is None for c in counts):
            return None
        return sum(c for c in counts if c is not None)

    # -- messages --------------------------------------------------------------------------

    def messages(self, topics: Collection[str] | str | None = None) -> Iterator[BagMessage]:
        """Every message (of ``topics``, if given), lazily, file by file in log-time order.

        Raises:
            BagError: where a file is truncated or corrupt, after the messages before it.
        """
        wanted = [topics] if isinstance(topics, str) else topics
        for index, f in enumerate(self._files):
            for schema, channel, message in f.messages(wanted):
                yield BagMessage(
                    topic=channel.topic,
                    msgtype=schema.name if schema is not None else "",
                    log_time_ns=message.log_time,
                    publish_time_ns=message.publish_time,
                    data=message.data,
                    _decoder=self._decoders.get(
                        index, f.path, schema, channel.message_encoding
                    ),
                )

    def __iter__(self) -> Iterator[BagMessage]:
        return self.messages()

    def close(self) -> None:
        for f in self._files:
            f.close()

    def __enter__(self) -> BagReader:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def _starts_with(path: Path, prefix: bytes) -> bool:
    try:
        with open(path, "rb") as fh:
            return fh.read(len(prefix)) == prefix
    except OSError:
        return False


def _sqlite_error(path: Path) -> BagError:
    return BagError(
        f"{path}: this bag uses the sqlite3 storage plugin; artcal reads MCAP bags only. "
        "Convert it with `ros2 bag convert` (storage_id: mcap) or record with "
        "`ros2 bag record -s mcap`"
    )


def _read_metadata(meta_path: Path) -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` mapping, checked for MCAP storage."""
    try:
        doc = yaml.safe_load(meta_path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as err:
        raise BagError(f"{meta_path}: cannot read: {err}") from err
    info = doc.get("rosbag2_bagfile_information") if isinstance(doc, dict) else None
    if not isinstance(info, dict):
        raise BagError(f"{meta_path}: no rosbag2_bagfile_information mapping; not a rosbag2 bag")
    storage = str(info.get("storage_identifier", ""))
    if storage == "sqlite3":
        raise _sqlite_error(meta_path.parent)
    if storage != "mcap":
        raise BagError(
            f"{meta_path}: storage_identifier is {storage!r}; artcal reads 'mcap' bags only"
        )
    if info.get("compression_mode"):
        raise BagError(
            f"{meta_path}: the bag is compressed per {info['compression_mode']} "
            f"({info.get('compression_format')}); decompress it first with `ros2 bag convert`"
        )
    return info
