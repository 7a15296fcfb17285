"""Launch the light stage on a full ROS 2 Jazzy install: driver, camera and classifier.

    ros2 launch lightstage_bringup lightstage.launch.py [params_file:=FILE.yaml] [use_trainer:=true]
        [use_acquisition:=true] [use_recorder:=false] [bag_dir:=DIR]

The graph records itself by default, as with `lightstage up`: the recorder writes a new bag
`bag_dir/rosbag2_YYYY_MM_DD-HH_MM_SS` (bag_dir default `out/bags`, relative to the working
directory); `use_recorder:=false` leaves it out.

The same nodes, names and parameters as `lightstage up` (lightstage_bringup.launcher), which
is what runs where `launch` is not available (the pip-only setup). Node names are the keys
of config/lightstage.yaml. Like `lightstage_graph.ros_env`, it keeps discovery on this
machine and uses the project's Fast DDS profile (large shared-memory segment for images).
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, SetEnvironmentVariable, UnsetEnvironmentVariable
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node

from lightstage_recording.layout import default_bag_name


def generate_launch_description():
    share = get_package_share_directory('lightstage_bringup')
    default_params = os.path.join(share, 'config', 'lightstage.yaml')
    params_file = LaunchConfiguration('params_file')
    # (name, package, executable in lib/<package>/); names match the launcher's registry
    nodes = [
        ('driver', 'lightstage_driver', 'driver_node'),
        ('camera', 'lightstage_camera', 'camera_node'),
        ('classifier', 'mux_classifier', 'classifier_node'),
    ]
    # started only when their launch argument is true: (name, package, executable, argument)
    optional = [
        ('trainer', 'mux_trainer', 'trainer_node', 'use_trainer'),
        ('acquisition', 'lightstage_camera', 'acquisition_node', 'use_acquisition'),
        ('recorder', 'lightstage_recording', 'recorder', 'use_recorder'),
    ]
    actions = [
        # the same settings as lightstage_graph.ros_env.ros_environment(): the profile confines
        # discovery to 127.0.0.1; rmw's LOCALHOST would add a UDPv4 transport bound to 0.0.0.0
        SetEnvironmentVariable('ROS_AUTOMATIC_DISCOVERY_RANGE', 'SYSTEM_DEFAULT'),
        UnsetEnvironmentVariable('ROS_STATIC_PEERS'),  # contacted even with LOCALHOST
        SetEnvironmentVariable('FASTRTPS_DEFAULT_PROFILES_FILE',
                               os.path.join(get_package_share_directory('lightstage_graph'),
                                            'config', 'fastdds_profile.xml')),
        DeclareLaunchArgument('params_file', default_value=default_params,
                              description='ROS parameters YAML for all nodes'),
        DeclareLaunchArgument('use_trainer', default_value='false',
                              description='also start the trainer node (Train action)'),
        DeclareLaunchArgument('use_acquisition', default_value='false',
                              description='also start the acquisition node (CaptureModel, '
                                          'CalibrateNoise actions)'),
        DeclareLaunchArgument('use_recorder', default_value='true',
                              description='record every topic and service call to an MCAP bag '
                                          '(recorder node; its section of params_file)'),
        DeclareLaunchArgument('bag_dir', default_value=os.path.join('out', 'bags'),
                              description='folder of the recorded bags; each launch writes a new '
                                          'rosbag2_YYYY_MM_DD-HH_MM_SS in it'),
    ]
    # a new bag per launch under bag_dir (overrides the params file's recorder output_dir)
    extra_parameters = {'recorder': [{'output_dir': PathJoinSubstitution(
        [LaunchConfiguration('bag_dir'), default_bag_name()])}]}
    for name, package, executable in nodes:
        actions.append(Node(package=package, executable=executable, name=name,
                            parameters=[params_file], output='screen', emulate_tty=True))
    for name, package, executable, argument in optional:
        actions.append(Node(package=package, executable=executable, name=name,
                            parameters=[params_file, *extra_parameters.get(name, [])],
                            output='screen', emulate_tty=True,
                            condition=IfCondition(LaunchConfiguration(argument))))
    return LaunchDescription(actions)
