"""ROS-free core of artcal_ros: numpy and OpenCV only."""
