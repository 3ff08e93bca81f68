"""ROS-free core of artcal_ros: numpy and OpenCV only."""

from artcal_ros.core import kernel_cache

kernel_cache.check()
