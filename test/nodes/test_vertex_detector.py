"""vertex_detector: a cloud per frame (empty when nothing is seen), acks, debug image on demand."""
from pathlib import Path
import sys

from absscale_ros import conversions
from absscale_ros.core import detect
from absscale_ros.nodes.vertex_detector import VertexDetectorNode
import numpy as np
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from ros_helpers import spin_until
from sensor_msgs.msg import Image, PointCloud2
from std_msgs.msg import Header

sys.path.insert(0, str(Path(__file__).parents[1] / 'core'))
import synth_targets as st  # noqa: E402


def _detector_and_camera(context, name: str, overrides: list[Parameter], depth: int):
    """A cube detector, a helper node publishing frames to it, its clouds and an executor."""
    node = VertexDetectorNode(context=context, parameter_overrides=[
        Parameter('target', value='cube'), *overrides])
    helper = Node(name, context=context)
    clouds: list[PointCloud2] = []
    helper.create_subscription(PointCloud2, '/absscale/vertices', clouds.append, depth)
    pub = helper.create_publisher(Image, '/absscale/frames', depth)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    executor.add_node(helper)
    return node, helper, pub, clouds, executor


def test_cloud_per_frame_ack_and_debug(context) -> None:
    node, helper, pub, clouds, executor = _detector_and_camera(context, 'vd_test_helper', [], 10)
    acks, debug = [], []
    helper.create_subscription(Header, '/absscale/ack', acks.append, 10)
    rng = np.random.default_rng(0)
    img, _, _ = st.render_cube(rng, *st.cube_pose(35, 25, 5.0))
    empty = st._finish(st._background(rng), rng)
    assert spin_until(executor, lambda: pub.get_subscription_count() > 0, 5.0)
    pub.publish(conversions.array_to_image_msg(img, 'bgr8', 1_000, 'camera'))
    assert spin_until(executor, lambda: len(clouds) == 1 and len(acks) == 1, 10.0)
    pts = conversions.cloud_msg_to_array(clouds[0])
    assert len(pts) == 7 and set(pts['target_type']) == {1}
    assert sorted(pts['vertex_id'] & 7) == [1, 2, 3, 4, 5, 6, 7]
    assert acks[0].frame_id == 'vertex_detector|/absscale/frames|/absscale/vertices'
    helper.create_subscription(Image, '/absscale/debug_image', debug.append, 10)
    assert spin_until(executor, lambda: node._debug_pub.get_subscription_count() > 0, 5.0)
    pub.publish(conversions.array_to_image_msg(empty, 'bgr8', 2_000, 'camera'))
    assert spin_until(executor, lambda: len(clouds) == 2 and len(debug) == 1, 10.0)
    assert clouds[1].width == 0  # looked and saw nothing
    assert acks[1].frame_id.endswith('/absscale/vertices,/absscale/debug_image')
    r = node.report()
    assert r['frames'] == 2 and r['frames_with_target'] == 1
    node.destroy_node()
    helper.destroy_node()


def test_vertices_array_layout() -> None:
    assert detect.vertices_array(detect.FrameDetections((), ('cube',))).shape == (0,)


def test_live_detector_keeps_to_its_rate(context) -> None:
    """With sensor-data QoS it looks at 10 of 30 frames a second, by stamp, and says so."""
    node, helper, pub, clouds, executor = _detector_and_camera(
        context, 'vd_rate_helper', [Parameter('qos', value='sensor_data'),
                                    Parameter('live_max_rate_hz', value=10.0)], 100)
    rng = np.random.default_rng(1)
    img, _, _ = st.render_cube(rng, *st.cube_pose(35, 25, 5.0))
    assert spin_until(executor, lambda: pub.get_subscription_count() > 0, 5.0)
    for k in range(9):  # 30 fps stamps, published slowly enough for best effort to keep all
        pub.publish(conversions.array_to_image_msg(img, 'bgr8', 1_000 + k * 33_333_333,
                                                   'camera'))
        assert spin_until(executor, lambda: node.report()['frames'] +
                          node.report()['frames_skipped_by_rate'] == k + 1, 10.0)
    assert spin_until(executor, lambda: len(clouds) == 3, 5.0)
    assert [conversions.stamp_to_ns(c.header.stamp) for c in clouds] == \
        [1_000, 1_000 + 3 * 33_333_333, 1_000 + 6 * 33_333_333]
    assert node.report()['frames_skipped_by_rate'] == 6
    node.destroy_node()
    helper.destroy_node()


def test_on_request_it_looks_only_at_the_frames_asked_for(context) -> None:
    """detect_on_request: frames are acknowledged at once without outputs, and only those
    the selector asks for get a cloud, whether the request comes before or after the frame."""
    node, helper, pub, clouds, executor = _detector_and_camera(
        context, 'vd_request_helper', [Parameter('detect_on_request', value=True),
                                       Parameter('pair_depth', value=3)], 10)
    acks: list[Header] = []
    helper.create_subscription(Header, '/absscale/ack', acks.append, 10)
    ask = helper.create_publisher(Header, '/absscale/detect_requests', 10)
    rng = np.random.default_rng(2)
    img, _, _ = st.render_cube(rng, *st.cube_pose(35, 25, 5.0))
    assert spin_until(executor, lambda: pub.get_subscription_count() > 0
                      and ask.get_subscription_count() > 0, 5.0)

    def frame(stamp: int) -> Image:
        return conversions.array_to_image_msg(img, 'bgr8', stamp, 'camera')

    for stamp in (1_000, 2_000, 3_000):
        pub.publish(frame(stamp))
    assert spin_until(executor, lambda: len(acks) == 3, 10.0)
    assert clouds == [] and {a.frame_id for a in acks} == {'vertex_detector|/absscale/frames|'}
    ask.publish(frame(2_000).header)  # after its frame: 1_000 was decided without
    assert spin_until(executor, lambda: len(clouds) == 1, 10.0)
    ask.publish(frame(4_000).header)  # before its frame (another process's selector)
    executor.spin_once(timeout_sec=0.2)
    assert len(clouds) == 1
    pub.publish(frame(4_000))
    assert spin_until(executor, lambda: len(clouds) == 2, 10.0)
    assert [conversions.stamp_to_ns(c.header.stamp) for c in clouds] == [2_000, 4_000]
    assert len(conversions.cloud_msg_to_array(clouds[0])) == 7
    r = node.report()
    assert r['frames'] == 2 and r['frames_not_requested'] == 2
    node.destroy_node()
    helper.destroy_node()


def test_sheet_names_list_from_parameters(context) -> None:
    # An empty list default (sheet.other_sheets) was declared a byte array: a YAML list of
    # names then stopped the node at startup (InvalidParameterTypeException).
    node = VertexDetectorNode(context=context, parameter_overrides=[
        Parameter('sheet.other_sheets', value=['a4'])])
    assert node._cfg.sheet.other_sheets == ('a4',)
    assert [m.name for m in node._cfg.sheet.models()][:2] == ['letter', 'a4']
    node.destroy_node()
    node = VertexDetectorNode(context=context)
    assert node._cfg.sheet.other_sheets == ()
    node.destroy_node()
