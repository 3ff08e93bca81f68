"""Image messages: sensor_msgs/Image and CompressedImage to numpy and back, without cv_bridge.

- :mod:`.raw`: sensor_msgs/Image bytes <-> numpy (the names below);
  :mod:`.compressed`: CompressedImage (jpeg, png) -> numpy, after :mod:`.compressed_header`
  checks the size the file declares; :mod:`.message_fields`: a message's fields, duck-typed.
- :mod:`.broken_frames`: why a frame could not be read, as the node counts it.
"""

from artcal_ros.core.errors import ImageFormatError
from artcal_ros.core.images.raw import (
    ENCODINGS,
    image_to_gray,
    image_to_numpy,
    lookup_encoding,
    numpy_to_image,
    to_gray,
)

__all__ = ["ENCODINGS", "ImageFormatError", "image_to_gray", "image_to_numpy",
           "lookup_encoding", "numpy_to_image", "to_gray"]
