"""ROS 2 message definitions that artcal_ros writes into MCAP bags.

A rosbag2 MCAP file carries, for every message type, a Schema record whose data is the
"complete message definition" in the ``ros2msg`` encoding: the type's own ``.msg`` text
first, then every type it depends on (recursively), each preceded by a line of 80 ``=``
and a line ``MSG: <package>/msg/<Type>``. Tools that do not know a type in advance (and
artcal's own reader) generate the CDR decoder from that text, so it has to be complete.

The texts below list the fields of the ROS 2 interfaces exactly (names, types, array
bounds); the type hashes are the RIHS01 hashes ROS 2 computes for those interfaces (the
``type_description_hash`` in metadata.yaml and the ``topic_type_hash`` channel metadata).
A test checks both against an independent implementation.

ROS-free: plain strings only.
"""

from __future__ import annotations

from dataclasses import dataclass

DELIMITER = "=" * 80

# Each entry: the fields of one interface, in declaration order.
_FIELDS: dict[str, str] = {
    "builtin_interfaces/msg/Time": ("int32 sec\nuint32 nanosec\n"),
    "std_msgs/msg/Header": (
        "# Acquisition time of the data and the coordinate frame it is expressed in.\n"
        "builtin_interfaces/Time stamp\n"
        "string frame_id\n"
    ),
    "sensor_msgs/msg/RegionOfInterest": (
        "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify\n"
    ),
    "sensor_msgs/msg/Image": (
        "# An uncompressed image; pixel (0, 0) is the top-left corner.\n"
        "std_msgs/Header header\n"
        "uint32 height\n"
        "uint32 width\n"
        "string encoding\n"
        "uint8 is_bigendian\n"
        "uint32 step  # bytes per row, including any padding\n"
        "uint8[] data  # step * height bytes\n"
    ),
    "sensor_msgs/msg/CompressedImage": (
        "# A compressed image (format: jpeg, png, ...).\n"
        "std_msgs/Header header\n"
        "string format\n"
        "uint8[] data\n"
    ),
    "sensor_msgs/msg/CameraInfo": (
        "# Intrinsic calibration of a camera.\n"
        "std_msgs/Header header\n"
        "uint32 height\n"
        "uint32 width\n"
        "string distortion_model\n"
        "float64[] d\n"
        "float64[9] k  # 3x3 row-major\n"
        "float64[9] r  # 3x3 row-major\n"
        "float64[12] p  # 3x4 row-major\n"
        "uint32 binning_x\n"
        "uint32 binning_y\n"
        "RegionOfInterest roi\n"
    ),
}

# Direct dependencies of each type, in the order their definitions follow the main text.
_DEPENDENCIES: dict[str, tuple[str, ...]] = {
    "builtin_interfaces/msg/Time": (),
    "std_msgs/msg/Header": ("builtin_interfaces/msg/Time",),
    "sensor_msgs/msg/RegionOfInterest": (),
    "sensor_msgs/msg/Image": ("std_msgs/msg/Header",),
    "sensor_msgs/msg/CompressedImage": ("std_msgs/msg/Header",),
    "sensor_msgs/msg/CameraInfo": ("std_msgs/msg/Header", "sensor_msgs/msg/RegionOfInterest"),
}

# RIHS01 type description hashes (REP 2011) of the ROS 2 interfaces above.
TYPE_HASHES: dict[str, str] = {
    "sensor_msgs/msg/Image": (
        "RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47"
    ),
    "sensor_msgs/msg/CompressedImage": (
        "RIHS01_15640771531571185e2efc8a100baf923961a4d15d5569652e6cb6691e8e371a"
    ),
    "sensor_msgs/msg/CameraInfo": (
        "RIHS01_b3dfd68ff46c9d56c80fd3bd4ed22c7a4ddce8c8348f2f59c299e73118e7e275"
    ),
    "std_msgs/msg/Header": (
        "RIHS01_f49fb3ae2cf070f793645ff749683ac6b06203e41c891e17701b1cb597ce6a01"
    ),
    "builtin_interfaces/msg/Time": (
        "RIHS01_b106235e25a4c5ed35098aa0a61a3ee9c9b18d197f398b0e4206cea9acf9c197"
    ),
}


@dataclass(frozen=True)
class MessageDefinition:
    """What a bag needs to know about one message type.

    Attributes:
        msgtype: full type name, e.g. ``sensor_msgs/msg/Image``.
        text: complete ``ros2msg`` definition (the type first, then its dependencies).
        type_hash: RIHS01 hash, or ``""`` when unknown (rosbag2 accepts an empty hash).
    """

    msgtype: str
    text: str
    type_hash: str


def _closure(msgtype: str) -> list[str]:
    """Every dependency of ``msgtype``, depth first, each once, the type itself excluded."""
    seen: list[str] = []

    def visit(name: str) -> None:
        for dep in _DEPENDENCIES[name]:
            if dep not in seen:
                seen.append(dep)
                visit(dep)

    visit(msgtype)
    return seen


def known_types() -> tuple[str, ...]:
    """The message types whose definitions are built in."""
    return tuple(sorted(_FIELDS))


def message_definition(msgtype: str) -> MessageDefinition:
    """The complete ``ros2msg`` definition of a built-in type.

    Args:
        msgtype: ``pkg/msg/Type`` (``pkg/Type`` is accepted and normalised).

    Raises:
        KeyError: the type is not built in; the message lists the ones that are.
    """
    name = normalize_type_name(msgtype)
    if name not in _FIELDS:
        raise KeyError(
            f"no built-in message definition for {msgtype!r}; known: {', '.join(known_types())}"
        )
    parts = [_FIELDS[name]]
    for dep in _closure(name):
        parts.append(f"{DELIMITER}\nMSG: {dep}\n{_FIELDS[dep]}")
    return MessageDefinition(name, "".join(parts), TYPE_HASHES.get(name, ""))


def normalize_type_name(msgtype: str) -> str:
    """``pkg/Type`` -> ``pkg/msg/Type``; ``pkg/msg/Type`` unchanged."""
    parts = msgtype.split("/")
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    return msgtype
