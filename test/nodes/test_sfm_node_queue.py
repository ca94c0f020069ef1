"""
The sfm's keyframe queue (``queue_keyframes``) under a lossless replay: queued keyframes are
acknowledged as DEFERRED and again once mapped, so the replay is drained only when every
keyframe's outputs were handled downstream, however slow the consumer.
"""
from concurrent.futures import Future
from pathlib import Path
import sys
import threading
import time

from absscale_ros import bagio, conversions
from absscale_ros.nodes import sfm_inputs
from absscale_ros.nodes.bag_replay import BagReplayNode
from absscale_ros.nodes.sfm import SfmNode
from absscale_ros.nodes.step_sink import StepSinkNode
import numpy as np
import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.serialization import serialize_message
from ros_helpers import spin_until
from test_sfm_node import _rows, _tracked

sys.path.insert(0, str(Path(__file__).parents[1] / 'core'))
import sfm_scenes  # noqa: E402


class SlowSink(StepSinkNode):
    """A consumer of the sfm's outputs slower than the sfm (a scale node under load)."""

    def _on_msg(self, data: bytes) -> None:
        time.sleep(0.3)
        super()._on_msg(data)


def _keyframe_bag(path: Path, seq: sfm_scenes.Sequence) -> int:
    """What the selector would publish per keyframe, as a bag; return the keyframe count."""
    rng = np.random.default_rng(5)
    stamps = [(k + 1) * 100_000_000 for k in range(len(seq.images_bgr))]
    with bagio.BagWriter(path) as writer:
        for k, image in enumerate(seq.images_bgr):
            s = stamps[k]
            vertices = _rows(sfm_scenes.detections(seq, k, rng)[0])
            for i, (topic, msgtype, msg) in enumerate((
                    ('/absscale/camera_info', 'sensor_msgs/msg/CameraInfo',
                     conversions.camera_model_to_info_msg(seq.camera, s, 'cam')),
                    ('/absscale/keyframe_motion', 'geometry_msgs/msg/TransformStamped',
                     conversions.tracked_step_to_msg(_tracked(seq, k, stamps), s)),
                    ('/absscale/keyframe_vertices', 'sensor_msgs/msg/PointCloud2',
                     conversions.array_to_cloud_msg(vertices, s, 'cam')),
                    ('/absscale/keyframes', 'sensor_msgs/msg/Image',
                     conversions.array_to_image_msg(image, 'bgr8', s, 'cam')))):
                writer.write(topic, msgtype, s + i, serialize_message(msg))
    return len(stamps)


@pytest.mark.parametrize('worker', [True, False])  # False: mapped on the executor's thread
def test_queued_keyframes_drain_only_once_a_slow_consumer_handled_their_outputs(
        context, tmp_path: Path, worker: bool) -> None:
    bag = tmp_path / 'keyframes.mcap'
    count = _keyframe_bag(bag, sfm_scenes.make_sequence('indoor_paper', 1, count=6))
    sfm = SfmNode(context=context, parameter_overrides=[Parameter('queue_keyframes', value=2),
                                                        Parameter('queue_worker', value=worker)])
    sink = SlowSink(context=context, parameter_overrides=[
        Parameter('topic', value='/absscale/target_points'),
        Parameter('msgtype', value='sensor_msgs/msg/PointCloud2')])
    replay = BagReplayNode(context=context, parameter_overrides=[
        Parameter(k, value=v) for k, v in {
            'bag': str(bag), 'mode': 'step', 'step_topics': '/absscale/keyframes',
            'step_window': 4, 'expect_nodes': 'sfm,step_sink',
            'step_timeout_s': 60.0}.items()])  # a loaded machine: no step given up
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(replay)
    executor.add_node(sfm)
    # The consumer spins on its own thread, as in a process of its own: its backlog must not
    # hold up the replay or the sfm (nor hide that the replay stopped waiting for it).
    sink_executor = SingleThreadedExecutor(context=context)
    sink_executor.add_node(sink)
    spinning = threading.Thread(target=lambda: spin_until(
        sink_executor, lambda: replay.drained or not context.ok(), timeout_s=300.0))
    spinning.start()
    try:
        assert spin_until(executor, lambda: replay.drained, timeout_s=300.0)
        # Drained means handled: every keyframe's target points reached the slow consumer,
        # and, at the end of the bag, those of the finished map (``adjust_at_end``).
        # (Acknowledged with no outputs once queued, the replay had drained while the sfm
        # was still mapping the last queued keyframes.)
        assert sink.count == count + 1
        assert replay.steps == count and replay.timeouts == 0
        # The queue was on. Not every step need be deferred: the worker (GTSAM holds the GIL)
        # can map a keyframe and acknowledge it before the callback that queued it does.
        # On the executor's thread every keyframe is mapped after the callback that queued it.
        assert replay.steps_deferred >= 1 if worker else replay.steps_deferred == count
        assert sfm.report()['keyframes_registered'] == count
    finally:
        spinning.join()
        sink_executor.shutdown()
        executor.shutdown()
        for node in (sfm, sink, replay):
            node.destroy_node()


def test_the_executor_queue_runs_its_calls_in_order_each_once_ready(context) -> None:
    node = Node('queue_test', context=context)
    queue = sfm_inputs.ExecutorQueue(node, None)
    features, ran = Future(), []
    first = queue.submit(features, ran.append, 1)
    second = queue.submit(None, ran.append, 2)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        spin_until(executor, lambda: False, timeout_s=0.2)
        assert ran == [] and not first.done()  # the second waits behind the first
        features.set_result(None)  # as the feature worker does
        assert spin_until(executor, second.done, timeout_s=5.0)
        assert ran == [1, 2]
        failing = queue.submit(None, lambda: 1 / 0)
        later = queue.submit(Future(), ran.append, 3)
        queue.run_through(later)  # the end of the bag: now, ready or not
        assert isinstance(failing.exception(), ZeroDivisionError) and ran == [1, 2, 3]
    finally:
        executor.shutdown()
        node.destroy_node()
