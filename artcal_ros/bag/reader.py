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
byte offset where reading broke. Messages before a break are yielded first; with
``messages(on_damage="stop")`` the iteration ends there instead and the break is added to
``reader.warnings``.

Order: an indexed file (one with a summary, as every finished recording has) is read in
log-time order, whatever order the messages were written in. A file without an index (a
recording cut short, or written unchunked without a summary) is read in file order, the
order the recorder wrote; a message earlier than the one before it is yielded where it is
and noted once in ``reader.warnings``.

A metadata.yaml that cannot be used (not YAML, not a rosbag2 mapping, listing files that
are not there) is set aside when the directory holds .mcap files: they are read alone and
the problem is in ``reader.warnings``. A channel without a decodable message definition
(another encoding, a missing or broken schema) is listed and its messages are yielded;
only ``decode()`` raises BagError, saying why.
"""

from __future__ import annotations

import contextlib
import io
import os
from collections.abc import Callable, Collection, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any, Literal

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
            # the definition parser prints its complaints; they are in the error already
            with contextlib.redirect_stderr(io.StringIO()):
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
        self.warnings: list[str] = []  # problems read past: unusable metadata, damage, order
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
        found = sorted(p.glob("*.mcap"))
        if meta_path.is_file():
            try:
                self.metadata = _read_metadata(meta_path)
                return _listed_files(meta_path, self.metadata)
            except _UnusableMetadataError as err:
                if not found:
                    raise BagError(str(err)) from None
                self.metadata = None
                self.warnings.append(
                    f"{err}; reading the .mcap files in {p} without it: "
                    f"{', '.join(q.name for q in found)}"
                )
                return found
        # No metadata.yaml (e.g. a recording that was killed): read the MCAP files alone.
        if found:
            return found
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

    def topics_text(self) -> str:
        """The recorded topics with their types, for messages: ``/a (sensor_msgs/msg/Image)``."""
        listed = [f"{t} ({kind or 'no type'})" for t, kind in sorted(self.topics.items())]
        return ", ".join(listed) or "no topics"

    @property
    def message_count(self) -> int | None:
        """Number of messages, from metadata.yaml or the MCAP statistics; None if unknown."""
        if self.metadata is not None and "message_count" in self.metadata:
            return int(self.metadata["message_count"])  # checked by _read_metadata
        counts = [f.message_count() for f in self._files]
        if any(c is None for c in counts):
            return None
        return sum(c for c in counts if c is not None)

    # -- messages --------------------------------------------------------------------------

    def messages(self, topics: Collection[str] | str | None = None, *,
                 on_damage: Literal["raise", "stop"] = "raise") -> Iterator[BagMessage]:
        """Every message (of ``topics``, if given), lazily, file by file (order: see above).

        Args:
            topics: a topic or topics to read; each must be in the bag.
            on_damage: at a truncated or corrupt record, "raise" BagError; "stop" ends the
                iteration there and appends the BagError's text to ``warnings``.

        Raises:
            BagError: a topic that is not in the bag (the message lists those that are,
                with their types); where a file is truncated or corrupt (after the
                messages before it), unless ``on_damage`` is "stop".
        """
        wanted = [topics] if isinstance(topics, str) else topics
        if wanted is not None:
            recorded = self.topics
            missing = [t for t in wanted if t not in recorded]
            if missing:
                raise BagError(
                    f"{self.path}: no topic {', '.join(missing)} in this bag; it has "
                    f"{self.topics_text()}"
                )
        try:
            yield from self._messages(wanted)
        except BagError as err:
            if on_damage != "stop":
                raise
            self.warnings.append(str(err))

    def _messages(self, wanted: Collection[str] | None) -> Iterator[BagMessage]:
        for index, f in enumerate(self._files):
            last_ns = -1
            for schema, channel, message in f.messages(wanted):
                if message.log_time < last_ns and f.summary is None:
                    self.warnings.append(
                        f"{f.path}: messages are not in log-time order (the file has no "
                        "index to sort them by); they are read in the order they were written"
                    )
                    last_ns = 2**64  # said once per file
                last_ns = max(last_ns, message.log_time)
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


class _UnusableMetadataError(BagError):
    """metadata.yaml cannot be used; the .mcap files may still be read without it."""


def _listed_files(meta_path: Path, info: dict[str, Any]) -> list[Path]:
    """The storage files metadata.yaml lists, each checked to exist."""
    names = info.get("relative_file_paths") or []
    if not isinstance(names, list):
        raise _UnusableMetadataError(
            f"{meta_path}: relative_file_paths is {names!r}, not a list of file names")
    paths = [meta_path.parent / str(name) for name in names]
    missing = [str(q) for q in paths if not q.is_file()]
    if missing:
        raise _UnusableMetadataError(
            f"{meta_path} lists files that do not exist: {', '.join(missing)}")
    if not paths:
        raise _UnusableMetadataError(f"{meta_path} lists no storage files (relative_file_paths)")
    return paths


def _read_metadata(meta_path: Path) -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` mapping, checked for MCAP storage."""
    try:
        doc = yaml.safe_load(meta_path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as err:
        first = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise _UnusableMetadataError(f"{meta_path}: cannot read it: {first}") from None
    info = doc.get("rosbag2_bagfile_information") if isinstance(doc, dict) else None
    if not isinstance(info, dict):
        raise _UnusableMetadataError(
            f"{meta_path}: no rosbag2_bagfile_information mapping; not a rosbag2 bag")
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
    count = info.get("message_count")
    if count is not None and (isinstance(count, bool) or not isinstance(count, int)):
        raise _UnusableMetadataError(f"{meta_path}: message_count is {count!r}, not a number")
    topics = info.get("topics_with_message_count")
    if topics is not None and not (
        isinstance(topics, list) and all(
            isinstance(e, dict) and isinstance(e.get("topic_metadata") or {}, dict)
            for e in topics)):
        raise _UnusableMetadataError(
            f"{meta_path}: topics_with_message_count is not a list of topic entries")
    return info
