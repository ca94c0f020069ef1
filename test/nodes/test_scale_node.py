"""The scale node publishes a metric cloud only on enough evidence; late subscribers get it."""
from absscale_ros import conversions
from absscale_ros.core import scale
from absscale_ros.nodes.common import LATCHED, RELIABLE
from absscale_ros.nodes.scale import ScaleNode
from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from ros_helpers import spin_until
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Float64MultiArray

LETTER = (0.2159, 0.2794)
UNIT_M = 0.25  # metres per SfM unit in this fake reconstruction


def _targets_msg(n_obs: int, stamp_ns: int, unit_m: float = UNIT_M) -> PointCloud2:
    corners = scale.model_vertices_m('sheet', LETTER)[[2, 3, 0, 1]] + [1.0, 2.0, 0.5]
    n = len(corners)
    extra = {'object_id': np.zeros(n, np.int32), 'vertex_id': np.arange(n, dtype=np.int32),
             'n_obs': np.full(n, n_obs, np.int32), 'angle_deg': np.full(n, 12.0, np.float32),
             'target_type': np.zeros(n, np.int32)}
    return conversions.xyz_rgb_to_cloud_msg(corners / unit_m, None, stamp_ns, 'sfm', extra)


def test_scaled_cloud_path_and_factor(context) -> None:
    node = ScaleNode(context=context)
    pub_node = rclpy.create_node('fake_sfm', context=context)
    pubs = {t: pub_node.create_publisher(PointCloud2, t, RELIABLE)
            for t in ('/absscale/target_points', '/absscale/sparse_cloud')}
    diags: list = []
    pub_node.create_subscription(DiagnosticArray, '/diagnostics', diags.append, 10)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    executor.add_node(pub_node)
    spin_until(executor, lambda: all(p.get_subscription_count() for p in pubs.values()))
    cloud = conversions.xyz_rgb_to_cloud_msg(np.array([[4.0, 0.0, 0.0], [0.0, 8.0, 0.0]]),
                                             np.array([[255, 0, 0], [0, 255, 0]], np.uint8), 1)
    pubs['/absscale/sparse_cloud'].publish(cloud)
    pubs['/absscale/target_points'].publish(_targets_msg(1, 1))  # seen once: not enough
    assert spin_until(executor, lambda: bool(diags))
    assert node.estimate is None and 'well-observed' in diags[-1].status[0].message
    pubs['/absscale/target_points'].publish(_targets_msg(6, 2))
    assert spin_until(executor, lambda: node.estimate is not None)
    assert node.estimate.factor == pytest.approx(UNIT_M, rel=1e-6)
    # A subscriber that arrives afterwards still gets the latest metric cloud and factor.
    late = rclpy.create_node('late_mapper', context=context)
    clouds, factors = [], []
    late.create_subscription(PointCloud2, '/scaled_cloud', clouds.append, LATCHED)
    late.create_subscription(Float64MultiArray, '/absscale/scale', factors.append, LATCHED)
    executor.add_node(late)
    assert spin_until(executor, lambda: clouds and factors)
    got = conversions.cloud_msg_to_array(clouds[-1])
    assert np.allclose(got['x'], [1.0, 0.0]) and np.allclose(got['y'], [0.0, 2.0])
    assert np.array_equal(conversions.unpack_rgb(got['rgb']), [[255, 0, 0], [0, 255, 0]])
    assert clouds[-1].header.frame_id == 'map'
    assert conversions.scale_from_msg(factors[-1])['factor'] == pytest.approx(UNIT_M)


def test_small_changes_that_add_up_are_republished(context) -> None:
    """min_change is measured from the factor last published, not from the last estimate."""
    node = ScaleNode(context=context, parameter_overrides=[
        rclpy.parameter.Parameter('min_change', value=0.01)])
    pub_node = rclpy.create_node('fake_sfm_steps', context=context)
    pub = pub_node.create_publisher(PointCloud2, '/absscale/target_points', RELIABLE)
    factors: list = []
    pub_node.create_subscription(Float64MultiArray, '/absscale/scale', factors.append, LATCHED)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    executor.add_node(pub_node)
    spin_until(executor, lambda: pub.get_subscription_count() > 0)
    for k, step in enumerate((0.0, 0.006, 0.012)):  # each step 0.6 % past the one before
        pub.publish(_targets_msg(6, 10 + k, UNIT_M * (1.0 + step)))
        assert spin_until(executor, lambda: len(node.history) == k + 1)
    assert spin_until(executor, lambda: len(factors) == 2)
    got = [conversions.scale_from_msg(f)['factor'] for f in factors]
    assert got == pytest.approx([UNIT_M, UNIT_M * 1.012], rel=1e-6)
