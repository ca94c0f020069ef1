"""frame_ingest and keyframe_selector as real rclpy nodes exchanging real messages."""
from pathlib import Path
import time

from absscale_ros import conversions
from absscale_ros.core import keyframes, replay
from absscale_ros.core.types import CameraModel
from absscale_ros.nodes import common
from absscale_ros.nodes.bag_replay import BagReplayNode
from absscale_ros.nodes.frame_ingest import FrameIngestNode
from absscale_ros.nodes.keyframe_selector import KeyframeSelectorNode
from absscale_ros.tools import bench_keyframes
from keyframe_scenes import write_sequence
import numpy as np
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from ros_helpers import spin_until
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from std_msgs.msg import Header


class Probe(Node):
    """Publishes camera input and records what the nodes publish and acknowledge."""

    def __init__(self, **kwargs) -> None:
        super().__init__('probe', **kwargs)
        self.got: dict[str, list] = {}
        self.acks: list[replay.Ack] = []
        for topic, cls in (('/absscale/frames', Image), ('/absscale/camera_info', CameraInfo),
                           ('/absscale/keyframes', Image),
                           ('/absscale/keyframe_vertices', PointCloud2)):
            self.got[topic] = []
            self.create_subscription(cls, topic, self.got[topic].append, common.RELIABLE)
        self.create_subscription(Header, common.ACK_TOPIC, lambda m: self.acks.append(
            replay.Ack.decode(m.frame_id, conversions.stamp_to_ns(m.stamp))), common.RELIABLE)
        self.image = self.create_publisher(Image, '/camera/image_raw', common.RELIABLE)
        self.info = self.create_publisher(CameraInfo, '/camera/camera_info', common.RELIABLE)
        self.frames = self.create_publisher(Image, '/absscale/frames', common.RELIABLE)
        self.vertices = self.create_publisher(PointCloud2, '/absscale/vertices', common.RELIABLE)


def _stamps(msgs: list) -> list[int]:
    return [conversions.stamp_to_ns(m.header.stamp) for m in msgs]


def _executor(context, *nodes: Node) -> SingleThreadedExecutor:
    executor = SingleThreadedExecutor(context=context)
    for node in nodes:
        executor.add_node(node)
    return executor


def test_step_replay_through_both_nodes_matches_the_core(context, tmp_path: Path) -> None:
    bag = tmp_path / 'scripted.mcap'
    write_sequence(bag, seed=2)
    ingest = FrameIngestNode(context=context)
    selector = KeyframeSelectorNode(context=context, parameter_overrides=[
        Parameter('use_vertices', value=False)])
    probe = Probe(context=context)
    bag_replay = BagReplayNode(context=context, parameter_overrides=[
        Parameter('bag', value=str(bag)), Parameter('mode', value='step'),
        Parameter('expect_nodes', value='frame_ingest,keyframe_selector')])
    executor = _executor(context, ingest, selector, probe, bag_replay)
    assert spin_until(executor, lambda: bag_replay.finished
                      and selector.report()['frames'] == 60, timeout_s=40.0)
    spin_until(executor, lambda: len(probe.got['/absscale/keyframe_vertices'])
               == len(selector.keyframe_stamps_ns), timeout_s=2.0)
    decisions, _ = bench_keyframes.select(str(bag), keyframes.KeyframeConfig())
    expected = [d.stamp_ns for d in decisions if d.keyframe]
    assert len(expected) >= 3
    assert selector.keyframe_stamps_ns == expected
    assert _stamps(probe.got['/absscale/keyframes']) == expected
    assert _stamps(probe.got['/absscale/keyframe_vertices']) == expected
    assert bag_replay.timeouts == 0 and bag_replay.steps == 60
    assert ingest.report()['frames_decoded'] == 60 and ingest.report()['frames_dropped'] == 0


def _model(w: int, h: int) -> CameraModel:
    return CameraModel(w, h, np.array([[0.9 * w, 0, w / 2], [0, 0.9 * w, h / 2], [0, 0, 1]]))


def _image(w: int, h: int, stamp: int) -> Image:
    pixels = (np.random.default_rng(stamp).random((h, w, 3)) * 255).astype(np.uint8)
    return conversions.array_to_image_msg(pixels, 'bgr8', stamp, 'cam')


def test_ingest_waits_for_camera_info_resizes_and_drops_mismatches(context) -> None:
    ingest = FrameIngestNode(context=context, parameter_overrides=[
        Parameter('image_topic', value='/camera/image_raw'), Parameter('compressed', value=False),
        Parameter('max_width_px', value=320), Parameter('info_wait_s', value=1.0)])
    probe = Probe(context=context)
    executor = _executor(context, ingest, probe)
    assert spin_until(executor, lambda: probe.image.get_subscription_count() == 1)
    probe.image.publish(_image(640, 360, 1))  # before any camera_info: held, not dropped
    assert spin_until(executor, lambda: ingest.report()['waiting'] == 1)
    assert probe.got['/absscale/frames'] == []
    probe.info.publish(conversions.camera_model_to_info_msg(_model(640, 360), 1, 'cam'))
    assert spin_until(executor, lambda: len(probe.got['/absscale/frames']) == 1
                      and len(probe.got['/absscale/camera_info']) == 1)
    frame, info = probe.got['/absscale/frames'][0], probe.got['/absscale/camera_info'][0]
    assert (frame.width, frame.height, frame.encoding) == (320, 180, 'bgr8')
    cam = conversions.camera_info_to_model(info)
    np.testing.assert_allclose(cam.K, _model(640, 360).resized(320, 180).K)
    probe.image.publish(_image(800, 600, 2))  # no camera_info of this size ever comes
    assert spin_until(executor, lambda: ingest.report()['frames_dropped'] == 1)
    assert spin_until(executor, lambda: len([a for a in probe.acks
                                             if a.node == 'frame_ingest']) == 2)
    acks = [a for a in probe.acks if a.node == 'frame_ingest']
    assert [(a.stamp_ns, a.outputs) for a in acks] == [(1, ('/absscale/frames',)), (2, ())]
    probe.info.publish(conversions.camera_model_to_info_msg(_model(800, 600), 3, 'cam'))
    probe.image.publish(_image(800, 600, 3))  # a resolution change re-initialises
    assert spin_until(executor, lambda: len(probe.got['/absscale/frames']) == 2)
    assert probe.got['/absscale/frames'][1].width == 320 and ingest.report()['reinitialised'] == 2


def test_selector_pairs_frames_with_vertices_by_stamp(context) -> None:
    selector = KeyframeSelectorNode(context=context)
    probe = Probe(context=context)
    executor = _executor(context, selector, probe)
    assert spin_until(executor, lambda: probe.vertices.get_subscription_count() == 1
                      and probe.frames.get_subscription_count() == 2)
    empty = np.zeros(0, [('u', '<f4'), ('v', '<f4'), ('object_id', '<i4')])
    probe.frames.publish(_image(320, 240, 10))
    probe.vertices.publish(conversions.array_to_cloud_msg(empty, 10, 'cam'))
    probe.vertices.publish(conversions.array_to_cloud_msg(empty, 11, 'cam'))  # before its frame
    probe.frames.publish(_image(320, 240, 11))
    assert spin_until(executor, lambda: selector.report()['frames'] == 2)
    assert spin_until(executor, lambda: len(probe.acks) == 4)
    assert sorted((a.stamp_ns, a.input_topic) for a in probe.acks) == [
        (10, '/absscale/frames'), (10, '/absscale/vertices'),
        (11, '/absscale/frames'), (11, '/absscale/vertices')]
    assert selector.keyframe_stamps_ns == [10]  # the first sharp frame starts the map
    assert spin_until(executor, lambda: _stamps(probe.got['/absscale/keyframe_vertices']) == [10])
    assert _stamps(probe.got['/absscale/keyframes']) == [10]


def test_selector_decides_frames_whose_vertices_never_come(context) -> None:
    """Live, the detector skips frames when behind: the selector must not stall on them."""
    selector = KeyframeSelectorNode(context=context, parameter_overrides=[
        Parameter('pair_depth', value=2)])
    probe = Probe(context=context)
    executor = _executor(context, selector, probe)
    assert spin_until(executor, lambda: probe.vertices.get_subscription_count() == 1
                      and probe.frames.get_subscription_count() == 2)
    for stamp in (20, 21, 22):  # no vertices for any of them
        probe.frames.publish(_image(320, 240, stamp))
    # pair_depth 2: the oldest is given up on waiting and decided alone. It would start the
    # map, but a keyframe without its vertices cannot add the target: it is passed over.
    assert spin_until(executor, lambda: selector.report()['frames'] == 1)
    assert selector.report()['unpaired'] == 1 and selector.keyframe_stamps_ns == []
    assert selector.report()['decisions'] == {'undetected': 1}
    assert spin_until(executor, lambda: [(a.stamp_ns, a.outputs) for a in probe.acks] == [
        (20, ())])
    # The next frame the detector looked at (nothing seen) starts the map.
    empty = np.zeros(0, [('u', '<f4'), ('v', '<f4'), ('object_id', '<i4')])
    probe.vertices.publish(conversions.array_to_cloud_msg(empty, 23, 'cam'))
    probe.frames.publish(_image(320, 240, 23))
    assert spin_until(executor, lambda: selector.keyframe_stamps_ns == [23])
    assert selector.report()['unpaired'] == 3
    assert spin_until(executor, lambda: _stamps(probe.got['/absscale/keyframe_vertices']) == [23])


def test_selector_asks_for_the_frames_it_needs_and_waits_for_them(context) -> None:
    """detect_on_request: the first sharp frame would start the map, so its vertices are
    asked for; the frames after it wait behind it, and are then decided without asking
    (noise: tracking lost, never a keyframe)."""
    selector = KeyframeSelectorNode(context=context, parameter_overrides=[
        Parameter('detect_on_request', value=True)])
    probe = Probe(context=context)
    requests: list[Header] = []
    probe.create_subscription(Header, '/absscale/detect_requests', requests.append,
                              common.RELIABLE)
    executor = _executor(context, selector, probe)
    assert spin_until(executor, lambda: probe.vertices.get_subscription_count() == 1
                      and probe.frames.get_subscription_count() == 2
                      and selector._request_pub.get_subscription_count() == 1)
    for stamp in (30, 31, 32):
        probe.frames.publish(_image(320, 240, stamp))
    assert spin_until(executor, lambda: len(requests) == 1)
    spin_until(executor, lambda: False, timeout_s=0.3)
    assert [conversions.stamp_to_ns(r.stamp) for r in requests] == [30]
    assert probe.acks == [] and selector.report()['frames'] == 0
    empty = np.zeros(0, [('u', '<f4'), ('v', '<f4'), ('object_id', '<i4')])
    probe.vertices.publish(conversions.array_to_cloud_msg(empty, 30, 'cam'))
    assert spin_until(executor, lambda: selector.report()['frames'] == 3)
    assert selector.keyframe_stamps_ns == [30] and len(requests) == 1
    assert spin_until(executor, lambda: len(probe.acks) == 4)
    assert [(a.stamp_ns, a.input_topic) for a in probe.acks] == [
        (30, '/absscale/frames'), (30, '/absscale/vertices'), (31, '/absscale/frames'),
        (32, '/absscale/frames')]
    assert spin_until(executor, lambda: _stamps(probe.got['/absscale/keyframe_vertices']) == [30])


def test_ingest_worker_applies_camera_info_in_arrival_order(context) -> None:
    """A camera_info of a new resolution that comes while the worker is still decoding
    frames of the old one is not applied to them (they would wait for an info that never
    comes, and be dropped)."""
    ingest = FrameIngestNode(context=context, parameter_overrides=[
        Parameter('image_topic', value='/camera/image_raw'), Parameter('compressed', value=False),
        Parameter('info_wait_s', value=0.5)])
    decode = ingest._decode
    ingest._decode = lambda msg: (time.sleep(0.4), decode(msg))[1]  # a slow frame
    probe = Probe(context=context)
    executor = _executor(context, ingest, probe)
    assert spin_until(executor, lambda: probe.image.get_subscription_count() == 1
                      and probe.info.get_subscription_count() == 1)
    for (w, h), stamp in (((640, 360), 1), ((800, 600), 2)):
        probe.info.publish(conversions.camera_model_to_info_msg(_model(w, h), stamp, 'cam'))
        spin_until(executor, lambda: False, timeout_s=0.1)
        probe.image.publish(_image(w, h, stamp))
        spin_until(executor, lambda: False, timeout_s=0.1)
    assert spin_until(executor, lambda: len(probe.got['/absscale/frames']) == 2, timeout_s=3.0)
    spin_until(executor, lambda: False, timeout_s=0.6)
    assert ingest.report()['frames_dropped'] == 0
    assert [f.width for f in probe.got['/absscale/frames']] == [640, 800]
    ingest.destroy_node()


def test_ingest_worker_bug_drops_the_frame_instead_of_stalling(context) -> None:
    """An unexpected exception on the decode worker (a bug, not a bad frame) is logged and
    the frame counted as dropped and acknowledged, so a lossless run does not wait for its
    step timeout; the next frame goes out."""
    ingest = FrameIngestNode(context=context, parameter_overrides=[
        Parameter('image_topic', value='/camera/image_raw'), Parameter('compressed', value=False)])
    assert ingest._worker is not None
    decode = ingest._decode
    ingest._decode = lambda msg: (_ for _ in ()).throw(RuntimeError('boom')) \
        if msg.header.stamp.nanosec == 1 else decode(msg)
    probe = Probe(context=context)
    executor = _executor(context, ingest, probe)
    assert spin_until(executor, lambda: probe.image.get_subscription_count() == 1
                      and probe.info.get_subscription_count() == 1)
    probe.info.publish(conversions.camera_model_to_info_msg(_model(640, 360), 1, 'cam'))
    spin_until(executor, lambda: False, timeout_s=0.1)
    for stamp in (1, 2):
        probe.image.publish(_image(640, 360, stamp))
    assert spin_until(executor, lambda: len(probe.got['/absscale/frames']) == 1, timeout_s=3.0)
    assert spin_until(executor, lambda: ingest.report()['frames_dropped'] == 1, timeout_s=3.0)
    ingest.destroy_node()
