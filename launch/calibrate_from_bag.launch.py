"""Calibrate from a recording: the replay node plays a bag into the calibrator node.

    ros2 launch artcal_ros calibrate_from_bag.launch.py      # the installed sample bag

or with a recording of your own:

    ros2 launch artcal_ros calibrate_from_bag.launch.py bag:=/path/to/bag \
        image_topic:=/camera/image_raw rate:=1.0

then, when the overlay says it is ready (about 25 s for the sample):

    ros2 service call /calibrator/calibrate std_srvs/srv/Trigger

The bag plays again and again until that call succeeds: the replay stops at the end of the
pass during which the calibrator published its result on ``/camera_info``. ``loop:=false``
plays it once.
"""

from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

from launch import LaunchDescription

# The calibrator's ``camera_info`` as resolved below: node "calibrator" in the root
# namespace, only ``image`` remapped. The replay watches it to end the loop.
CAMERA_INFO = "/camera_info"


def generate_launch_description() -> LaunchDescription:
    share = FindPackageShare("artcal_ros")
    bag = LaunchConfiguration("bag")
    image_topic = LaunchConfiguration("image_topic")
    rate = LaunchConfiguration("rate")
    loop = LaunchConfiguration("loop")
    params_file = LaunchConfiguration("params_file")
    return LaunchDescription([
        DeclareLaunchArgument("bag", default_value=PathJoinSubstitution([share, "bags", "sample"]),
                              description="rosbag2 MCAP directory or .mcap file"),
        DeclareLaunchArgument("image_topic", default_value="/camera/image_raw",
                              description="the recorded sensor_msgs/Image topic"),
        DeclareLaunchArgument("rate", default_value="1.0",
                              description="playback speed (1.0: as recorded; the "
                                          "calibrator tracks every frame it receives)"),
        DeclareLaunchArgument("loop", default_value="true",
                              description="play the bag again and again until ~/calibrate "
                                          "succeeds (false: once)"),
        DeclareLaunchArgument("params_file",
                              default_value=PathJoinSubstitution(
                                  [share, "config", "calibrator.yaml"]),
                              description="board and calibration parameters"),
        Node(package="artcal_ros", executable="calibrator", name="calibrator",
             output="screen", parameters=[params_file],
             remappings=[("image", image_topic)]),
        Node(package="artcal_ros", executable="replay", name="replay", output="screen",
             parameters=[{"bag": bag, "rate": rate, "loop": loop,
                          "until_topic": CAMERA_INFO}]),
    ])
