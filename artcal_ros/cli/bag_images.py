"""Images from a recording for the ``artcal`` verbs: one message as an image, and how many
frames a time budget still affords."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from artcal_ros.bag.reader import BagMessage

__all__ = ["frames_affordable", "message_image"]


def message_image(message: BagMessage) -> np.ndarray:
    """The image of a ``sensor_msgs/Image`` or ``CompressedImage`` message.

    Raises:
        BagError: the message does not decode.
        ImageFormatError: its image does not convert (encoding, size, data).
    """
    from artcal_ros.core.images import image_to_numpy
    from artcal_ros.core.images.compressed import compressed_to_numpy

    msg = message.decode()
    if message.msgtype.endswith("CompressedImage"):
        return compressed_to_numpy(msg)
    return image_to_numpy(msg)


def frames_affordable(left: int, done: int, elapsed_s: float, budget_s: float) -> int:
    """Frames still to take: ``left`` at most, and no more than the rest of ``budget_s``
    seconds affords at the pace of the ``done`` frames so far (``elapsed_s`` seconds).

    ``budget_s`` 0: no budget; with no frame done yet there is no pace to judge by.
    """
    if budget_s <= 0 or done <= 0:
        return left
    per_frame_s = max(elapsed_s / done, 1e-9)
    return min(left, int(max(budget_s - elapsed_s, 0.0) / per_frame_s))
