"""The header stamp of a recorded message, read from its CDR bytes without decoding it.

Messages that begin with a ``std_msgs/Header`` (sensor_msgs/Image, CompressedImage,
CameraInfo, ...) carry the stamp first: after CDR's 4-byte encapsulation header come
``stamp.sec`` (int32) and ``stamp.nanosec`` (uint32), in the byte order the encapsulation
names. Reading those 8 bytes gives the capture time of a whole recording's images without
copying their pixels (pairing a rig's images by stamp needs every stamp, the pixels of
the paired ones only).
"""

from __future__ import annotations

import struct

from artcal_ros.bag.reader import BagMessage

# CDR encapsulation identifiers (the first two bytes): plain and parameter-list CDR
_LITTLE = (b"\x00\x01", b"\x00\x03")
_BIG = (b"\x00\x00", b"\x00\x02")


def header_stamp_ns(message: BagMessage) -> int:
    """The header stamp of ``message`` (a type that begins with std_msgs/Header), nanoseconds;
    its receive time (``log_time_ns``) when the bytes are too short, of an unknown
    encapsulation, or the stamp is zero (a driver that does not stamp)."""
    data = message.data
    if len(data) < 12 or data[:2] not in _LITTLE + _BIG:
        return message.log_time_ns
    order = "<" if data[:2] in _LITTLE else ">"
    sec, nanosec = struct.unpack_from(order + "iI", data, 4)
    if sec == 0 and nanosec == 0:
        return message.log_time_ns
    return sec * 1_000_000_000 + nanosec
