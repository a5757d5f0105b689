"""Launch the compensator with the bundled parameters (or params_file:=...).

ros2 launch strain_comp compensator.launch.py [params_file:=/path/params.yaml]
    [use_sim_time:=true] [namespace:=robot1]
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue


def generate_launch_description() -> LaunchDescription:
    default_params = os.path.join(get_package_share_directory("strain_comp"), "config",
                                  "compensator_params.yaml")
    return LaunchDescription([
        DeclareLaunchArgument("params_file", default_value=default_params,
                              description="Node parameters (<node>: ros__parameters: ...)."),
        DeclareLaunchArgument("use_sim_time", default_value="false",
                              description="Use /clock, e.g. with ros2 bag play --clock."),
        DeclareLaunchArgument("namespace", default_value="",
                              description="Namespace of the node and its relative topics."),
        Node(package="strain_comp", executable="compensator", name="compensator",
             namespace=LaunchConfiguration("namespace"), output="screen",
             parameters=[LaunchConfiguration("params_file"),
                         {"use_sim_time": ParameterValue(LaunchConfiguration("use_sim_time"),
                                                         value_type=bool)}]),
    ])
