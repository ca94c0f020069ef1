"""
Start the absscale_ros graph on a machine with a full ROS 2 Jazzy install.

  ros2 launch absscale_ros absscale.launch.py config:=indoor_paper \
      image:=/camera/image_raw/compressed camera_info:=/camera/camera_info [dense:=true]

Then feed it a camera driver, `ros2 bag play BAG`, or `video_source`.
"""
import os
from pathlib import Path

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from absscale_ros import params as params_module

# Pipeline order; a node whose executable is not installed yet is skipped.
NODES = ['frame_ingest', 'vertex_detector', 'keyframe_selector', 'sfm', 'scale']


def _nodes(context, *args, **kwargs):
    share = get_package_share_directory('absscale_ros')
    config = LaunchConfiguration('config').perform(context)
    params = config if config.endswith('.yaml') else os.path.join(share, 'config',
                                                                  config + '.yaml')
    lib = os.path.join(os.path.dirname(os.path.dirname(share)), 'lib', 'absscale_ros')
    remaps = [('/camera/image_raw/compressed', LaunchConfiguration('image').perform(context)),
              ('/camera/camera_info', LaunchConfiguration('camera_info').perform(context))]
    dense = LaunchConfiguration('dense').perform(context).lower() in ('true', '1')
    # With the dense node, it owns /scaled_cloud and the sparse metric cloud moves aside
    # (as `absscale run` does for `dense: enabled: true`).
    extra = {'scale': [{'cloud_topic': '/absscale/sparse_cloud_metric'}]} if dense else {}
    # 'sheet: auto' scales by the detector's one sheet, as `absscale run` does
    # (params.detected_sheet: an A6 card fits A4's shape).
    sheet = params_module.scale_sheet(params_module.load_yaml(Path(params)))
    if sheet:
        extra.setdefault('scale', []).append(sheet)
    names = NODES + (['dense'] if dense else [])
    # Frames are 2.7 MB: a shared-memory segment that holds them whole, unless one is set.
    env = {} if os.environ.get('FASTRTPS_DEFAULT_PROFILES_FILE') else {
        'FASTRTPS_DEFAULT_PROFILES_FILE': os.path.join(share, 'config', 'fastdds_shm.xml')}
    return [Node(package='absscale_ros', executable=name, name=name, output='screen',
                 parameters=[params, *extra.get(name, [])], remappings=remaps,
                 additional_env=env)
            for name in names if os.path.exists(os.path.join(lib, name))]


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument('config', default_value='indoor_paper',
                              description='indoor_paper, outdoor_cube, auto or a YAML path'),
        DeclareLaunchArgument('image', default_value='/camera/image_raw/compressed',
                              description='camera image topic (Image or CompressedImage)'),
        DeclareLaunchArgument('camera_info', default_value='/camera/camera_info',
                              description='camera_info topic'),
        DeclareLaunchArgument('dense', default_value='false',
                              description='true: also the dense node (dense cloud on '
                              '/scaled_cloud, sparse on /absscale/sparse_cloud_metric)'),
        OpaqueFunction(function=_nodes),
    ])
