"""bag_replay publishes every message, in order and byte-identical, into a real subscriber."""
from pathlib import Path
import time

from absscale_ros import conversions
from absscale_ros.nodes import common
from absscale_ros.nodes.bag_replay import BagReplayNode
from absscale_ros.nodes.step_sink import StepSinkNode
from bagfactory import IMAGE_TOPIC, INFO_TOPIC, write_camera_bag
import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from ros_helpers import spin_until
from std_msgs.msg import Header


def _graph(context, bag: Path, **replay_params):
    sink = StepSinkNode(context=context, parameter_overrides=[
        Parameter('topic', value=IMAGE_TOPIC), Parameter('keep_bytes', value=True)])
    overrides = {'bag': str(bag), 'expect_nodes': 'step_sink', **replay_params}
    replay = BagReplayNode(context=context, parameter_overrides=[
        Parameter(k, value=v) for k, v in overrides.items()])
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(sink)
    executor.add_node(replay)
    return sink, replay, executor


@pytest.mark.parametrize('mode', ['step', 'rate'])
def test_every_frame_arrives_in_order_byte_identical(context, tmp_path: Path, mode: str) -> None:
    bag = tmp_path / 'cam.mcap'
    sent = write_camera_bag(bag, frames=30)
    sink, replay, executor = _graph(context, bag, mode=mode, rate=1.0)
    info_sink = StepSinkNode('info_sink', context=context, parameter_overrides=[
        Parameter('topic', value=INFO_TOPIC), Parameter('keep_bytes', value=True),
        Parameter('msgtype', value='sensor_msgs/msg/CameraInfo')])
    executor.add_node(info_sink)
    t0 = time.monotonic()
    assert spin_until(executor, lambda: replay.finished and len(sink.received) == len(sent)
                      and len(info_sink.received) == 30,
                      timeout_s=20.0), f'{len(sink.received)}/{len(sent)} frames arrived'
    elapsed = time.monotonic() - t0
    assert sink.received == sent  # same bytes, same order
    assert len(info_sink.received) == 30
    assert replay.published == 60 and replay.timeouts == 0
    if mode == 'rate':  # 30 frames at 30 fps: about one second of bag time
        assert 0.9 < elapsed < 3.0, elapsed


def test_step_mode_waits_for_the_consumer(context, tmp_path: Path) -> None:
    """With a consumer that never acknowledges, only one frame goes out until the timeout."""
    bag = tmp_path / 'cam.mcap'
    write_camera_bag(bag, frames=5)
    sink, replay, executor = _graph(context, bag, mode='step', step_timeout_s=0.5,
                                    topics=IMAGE_TOPIC)
    sink._ack.ack = lambda *a, **k: None  # a consumer that swallows frames
    spin_until(executor, lambda: len(sink.received) >= 1)
    spin_until(executor, lambda: False, timeout_s=0.3)
    assert len(sink.received) == 1 and replay.steps == 1
    assert spin_until(executor, lambda: replay.timeouts >= 1, timeout_s=5.0)


def test_step_mode_ends_with_an_end_of_bag_step(context, tmp_path: Path) -> None:
    """Once every frame is acknowledged, an end-of-bag step stamped after the last frame
    goes out; the replay is drained only when its subscriber (the sfm) acknowledges it."""
    bag = tmp_path / 'cam.mcap'
    write_camera_bag(bag, frames=5)
    sink, replay, executor = _graph(context, bag, mode='step', topics=IMAGE_TOPIC)
    ender = Node('ender', context=context)
    ack, got = common.StepAck(ender), []
    ender.create_subscription(Header, common.END_OF_BAG_TOPIC, got.append, common.RELIABLE)
    executor.add_node(ender)
    assert spin_until(executor, lambda: len(got) == 1, timeout_s=20.0)
    assert len(sink.received) == 5 and replay.finished
    assert conversions.stamp_to_ns(got[0].stamp) > max(replay.published_at)
    spin_until(executor, lambda: False, timeout_s=0.3)
    assert not replay.drained and len(got) == 1  # waiting for the answer
    ack.ack(got[0].stamp, common.END_OF_BAG_TOPIC)
    assert spin_until(executor, lambda: replay.drained)
    assert replay.timeouts == 0 and replay.steps == 5


def test_step_replay_queries_the_graph_sparingly_while_it_waits(
        context, tmp_path: Path) -> None:
    """Waiting for a node that never comes, the graph is queried every 50 ms (not on every
    tick); the replay still starts after ``startup_timeout_s`` and delivers every frame."""
    bag = tmp_path / 'cam.mcap'
    sent = write_camera_bag(bag, frames=5)
    sink, replay, executor = _graph(context, bag, mode='step', topics=IMAGE_TOPIC,
                                    expect_nodes='step_sink,never_started',
                                    startup_timeout_s=1.0)
    checks = []
    ready = replay._ready
    replay._ready = lambda: checks.append(time.monotonic()) or ready()
    assert spin_until(executor, lambda: replay.finished and len(sink.received) == 5,
                      timeout_s=20.0)
    assert sink.received == sent and replay.timeouts == 0
    assert checks[-1] - checks[0] >= 0.9  # it waited for the missing node
    assert len(checks) <= 1.0 / 0.05 + 5  # not once a millisecond


def test_topic_filter_remap_and_offset(context, tmp_path: Path) -> None:
    bag = tmp_path / 'cam.mcap'
    sent = write_camera_bag(bag, frames=30)
    sink2 = StepSinkNode('other_sink', context=context, parameter_overrides=[
        Parameter('topic', value='/other'), Parameter('keep_bytes', value=True)])
    sink, replay, executor = _graph(context, bag, mode='fast', topics=IMAGE_TOPIC,
                                    remap=f'{IMAGE_TOPIC}:=/other',
                                    start_offset_s=0.49)  # frames 15..29
    assert replay.topic_types() == {'/other': 'sensor_msgs/msg/CompressedImage'}
    executor.add_node(sink2)
    assert spin_until(executor, lambda: replay.finished and len(sink2.received) == 15)
    assert sink2.received == sent[15:] and sink.received == []
