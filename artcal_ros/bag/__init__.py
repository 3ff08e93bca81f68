"""rosbag2 recordings (MCAP) read and written without rclpy::

    from artcal_ros.bag import BagReader, BagWriter
"""

from artcal_ros.bag.reader import BagMessage, BagReader
from artcal_ros.bag.writer import BagWriter

__all__ = ["BagMessage", "BagReader", "BagWriter"]
