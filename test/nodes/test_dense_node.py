"""The dense node: rendered keyframes and metric poses in, a dense metric cloud out, acked."""
from absscale_ros import conversions
from absscale_ros.nodes.common import ACK_TOPIC, LATCHED, RELIABLE
from absscale_ros.nodes.dense import DenseNode
from dense_scenes import sideways_keyframes
import numpy as np
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from ros_helpers import spin_until
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from std_msgs.msg import Header
from nav_msgs.msg import Path

T0_NS = 1_700_000_000_000_000_000


def _path(poses: list[np.ndarray], stamp_ns: int) -> Path:
    rows = np.array([[*T[:3, 3], *Rotation.from_matrix(T[:3, :3]).as_quat()] for T in poses])
    stamps = [T0_NS + k for k in range(len(poses))]
    return conversions.poses_to_path_msg(rows, stamps, 'map', stamp_ns)


def test_dense_cloud_from_keyframes_and_metric_path(context) -> None:
    images, cam, poses, mesh = sideways_keyframes()
    node = DenseNode(context=context, parameter_overrides=[
        Parameter('stereo.scale', value=0.5)])  # 320x180: coarse but quick
    fake = rclpy.create_node('fake_upstream', context=context)
    info_pub = fake.create_publisher(CameraInfo, '/absscale/camera_info', RELIABLE)
    kf_pub = fake.create_publisher(Image, '/absscale/keyframes', RELIABLE)
    path_pub = fake.create_publisher(Path, '/absscale/scaled_path', LATCHED)
    clouds, acks = [], []
    fake.create_subscription(PointCloud2, '/scaled_cloud', clouds.append, LATCHED)
    fake.create_subscription(Header, ACK_TOPIC, acks.append, RELIABLE)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    executor.add_node(fake)
    assert spin_until(executor, lambda: kf_pub.get_subscription_count() and
                      path_pub.get_subscription_count() and info_pub.get_subscription_count())
    for k, image in enumerate(images):
        stamp = T0_NS + k
        info_pub.publish(conversions.camera_model_to_info_msg(cam, stamp, 'camera'))
        spin_until(executor, lambda: False, 0.05)
        kf_pub.publish(conversions.array_to_image_msg(image, 'bgr8', stamp, 'camera'))
        assert spin_until(executor, lambda: len(acks) == k + 1)
        assert acks[-1].frame_id == 'dense|/absscale/keyframes|'  # nothing published yet
    assert not clouds  # no metric pose yet, no cloud
    path_pub.publish(_path(poses[:4], T0_NS + 3))
    assert spin_until(executor, lambda: clouds and len(acks) == len(images) + 1, 60.0)
    assert acks[-1].frame_id == 'dense|/absscale/scaled_path|/scaled_cloud'
    first = clouds[-1]
    # Pairs past the per-update budget follow from the node's timer; then two more keyframes.
    assert spin_until(executor, lambda: not node._fusion.backlog, 60.0)
    path_pub.publish(_path(poses, T0_NS + 5))
    assert spin_until(executor, lambda: conversions.stamp_to_ns(clouds[-1].header.stamp) ==
                      T0_NS + 5 and not node._fusion.backlog, 60.0)
    spin_until(executor, lambda: False, 0.3)  # the last catch-up's cloud
    xyz, rgb, normals = conversions.cloud_msg_to_xyz_rgb_normals(clouds[-1])
    assert normals is not None and rgb is not None
    assert len(xyz) > 2000 and len(xyz) > first.width > 0
    assert conversions.stamp_to_ns(clouds[-1].header.stamp) == T0_NS + 5
    assert clouds[-1].header.frame_id == 'map'
    depth = np.median(np.linalg.norm(xyz - poses[0][:3, 3], axis=1))
    assert np.median(mesh.distance(xyz)) < 0.01 * depth
    report = node.report()
    # Depth 1: a subscriber may miss intermediate clouds, never the last.
    assert report['keyframes_fused'] == len(images) and len(report['update_s']) >= len(clouds) >= 2
