"""Launch the landing_zone ``assessor`` node with a parameter file and the robot's topic names.

    ros2 launch landing_zone assessor.launch.py
    ros2 launch landing_zone assessor.launch.py points:=/cloud_registered odometry:=/Odometry
    ros2 launch landing_zone assessor.launch.py points:=/cloud_registered_body \\
        odometry:=/Odometry cloud_frame:=body params_file:=/path/to/robot.yaml
    ros2 launch landing_zone assessor.launch.py points:=/lidar/points \\
        sensor_pose:=/lidar/pose use_sim_time:=true

Arguments: ``params_file`` (default: the installed config/assessor.yaml), the input topics
``points``, ``sensor_pose`` and ``odometry`` (remaps of the node's inputs; the node uses
whichever pose input is published), ``cloud_frame`` (fixed | body | sensor; empty: the
parameter file's), ``use_sim_time`` and ``namespace``. ``sensor_offset`` and every other
parameter go in the parameter file (docs/ROS_NODE.md).
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

# name -> (default, description); the test reads this table from the source
ARGUMENTS = {
    'params_file': ('', 'Parameter file of the node; empty: the installed config/assessor.yaml'),
    'points': ('points', 'Topic of the LiDAR clouds (sensor_msgs/PointCloud2)'),
    'sensor_pose': ('sensor_pose', "Topic of the sensor's pose (geometry_msgs/PoseStamped)"),
    'odometry': ('odometry', "Topic of the body's odometry (nav_msgs/Odometry)"),
    'cloud_frame': ('', 'fixed | body | sensor; empty: as the parameter file says'),
    'use_sim_time': ('false', 'Take time from /clock (a played bag)'),
    'namespace': ('', 'Namespace of the node'),
}


def _node(context):
    def arg(name):
        return LaunchConfiguration(name).perform(context)

    params_file = arg('params_file') or os.path.join(
        get_package_share_directory('landing_zone'), 'config', 'assessor.yaml')
    overrides = {'use_sim_time': arg('use_sim_time').lower() in ('true', '1', 'yes')}
    if arg('cloud_frame'):
        overrides['cloud_frame'] = arg('cloud_frame')
    return [Node(package='landing_zone', executable='assessor', name='assessor',
                 namespace=arg('namespace'), output='screen', emulate_tty=True,
                 parameters=[params_file, overrides],
                 remappings=[('points', arg('points')), ('sensor_pose', arg('sensor_pose')),
                             ('odometry', arg('odometry'))])]


def generate_launch_description():
    return LaunchDescription(
        [DeclareLaunchArgument(name, default_value=default, description=text)
         for name, (default, text) in ARGUMENTS.items()] + [OpaqueFunction(function=_node)])
