"""Rig frames from the time stamps of several cameras' images (approximate synchronisation).

Images of different cameras whose stamps lie within a tolerance of the group's first stamp
form one rig frame, as camera_calibration's ``--approximate`` pairs a stereo camera's
images. Each image joins at most one frame; an image with no partner within the tolerance
is left unpaired::

    frames, unpaired = pair_by_stamp({"left": [0, 100], "right": [3, 180]}, tolerance_ns=10)
    # frames == [{"left": 0, "right": 0}], unpaired == {"left": 1, "right": 1}
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from artcal_ros.core.errors import ParameterError


def group_end(events: Sequence[tuple[Any, ...]], i: int, tolerance_ns: int) -> int:
    """The end (exclusive) of the rig frame that opens at ``events[i]``.

    ``events``: (stamp ns, camera, anything) sorted by stamp. The frame takes the events
    after ``i`` within ``tolerance_ns`` of its first stamp, until a camera already in it
    comes again. The one rule of :func:`pair_by_stamp` and of the live node's pairing.
    """
    start, first = events[i][0], events[i][1]
    names = {first}
    j = i + 1
    while j < len(events) and events[j][0] - start <= tolerance_ns:
        name = events[j][1]
        if name in names:
            break   # a camera's next image opens the next frame
        names.add(name)
        j += 1
    return j


def pair_by_stamp(stamps: Mapping[str, Sequence[int]], *, tolerance_ns: int
                  ) -> tuple[list[dict[str, int]], dict[str, int]]:
    """Group the cameras' images into rig frames by stamp.

    The images of all cameras are swept in time order; a frame opens at the earliest image
    not yet grouped and takes, of each other camera, the images that follow within
    ``tolerance_ns`` of that first stamp, until a camera already in it comes again (its
    next image opens the next frame). A frame of fewer than two cameras is no rig frame:
    its image is counted as unpaired.

    Args:
        stamps: camera name -> its images' stamps, nanoseconds, in recording order.
        tolerance_ns: the largest stamp difference within a frame, nanoseconds (>= 0).

    Returns:
        (frames: each ``{camera: index into its stamps}`` for the cameras in it, in time
        order; unpaired: camera -> images left out).
    """
    if tolerance_ns < 0:
        raise ParameterError(f"pair_by_stamp: tolerance {tolerance_ns} ns must be >= 0")
    events = sorted((int(s), name, k) for name, seq in stamps.items()
                    for k, s in enumerate(seq))
    unpaired = {name: 0 for name in stamps}
    frames: list[dict[str, int]] = []
    i = 0
    while i < len(events):
        first = events[i][1]
        j = group_end(events, i, tolerance_ns)
        group = {name: k for _, name, k in events[i:j]}
        if len(group) >= 2:
            frames.append(group)
        else:
            unpaired[first] += 1
        i = j
    return frames, unpaired
