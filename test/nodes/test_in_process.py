"""in_process: messages handed to subscriptions of the same process, or through DDS."""
import contextlib
import threading
from typing import Callable, Iterator

from absscale_ros import conversions
from absscale_ros.nodes import common, in_process
import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from ros_helpers import spin_until
from sensor_msgs.msg import Image

TOPIC = '/absscale/frames'


def _frame(k: int) -> Image:
    return conversions.array_to_image_msg(np.full((4, 6, 3), k, np.uint8), 'bgr8', k + 1, 'cam')


def _stamps(msgs: list[Image]) -> list[int]:
    return [conversions.stamp_to_ns(m.header.stamp) for m in msgs]


@pytest.mark.parametrize('events', [True, False])
def test_frames_are_handed_to_the_subscriptions_beside_the_publisher(context,
                                                                     events: bool) -> None:
    source, a, b = (Node(name, context=context) for name in ('source', 'a', 'b'))
    got_a: list[Image] = []
    got_b: list[Image] = []
    # Kept, as the nodes keep theirs: the registry holds subscriptions weakly.
    subs = [in_process.Subscription(a, Image, TOPIC, got_a.append, common.RELIABLE),
            in_process.Subscription(b, Image, TOPIC, got_b.append, common.RELIABLE)]
    pub = in_process.Publisher(source, Image, TOPIC, common.RELIABLE)
    executor = common.single_threaded_executor(context) if events \
        else SingleThreadedExecutor(context=context)
    for node in (source, a, b):
        executor.add_node(node)
    sent = [_frame(k) for k in range(20)]
    # From another thread, as the frame decoder's worker publishes.
    worker = threading.Thread(target=lambda: [pub.publish(m) for m in sent])
    worker.start()
    assert spin_until(executor, lambda: len(got_a) == len(got_b) == len(sent), 5.0)
    worker.join()
    assert pub.handed == len(sent) and not pub.through_dds
    assert [id(m) for m in got_a] == [id(m) for m in sent]  # the objects themselves, in order
    assert [id(m) for m in got_b] == [id(m) for m in sent]
    executor.shutdown()
    del subs


@contextlib.contextmanager
def _subscriber_elsewhere(context) -> Iterator[tuple[list[Image], Callable[[], bool]]]:
    """Another process's subscriber (another context, another DDS participant): what it
    received, and a step that spins it once (for ``spin_until``'s condition)."""
    got: list[Image] = []
    other_context = rclpy.Context()
    rclpy.init(context=other_context, domain_id=context.get_domain_id())
    try:
        other = Node('other', context=other_context)
        other.create_subscription(Image, TOPIC, got.append, common.RELIABLE)
        executor = common.single_threaded_executor(other_context)
        executor.add_node(other)

        def spin_once() -> bool:
            executor.spin_once(timeout_sec=0.01)
            return False
        yield got, spin_once
        executor.shutdown()
    finally:
        rclpy.try_shutdown(context=other_context)


def test_a_subscriber_elsewhere_gets_every_frame_through_dds_and_none_twice(context) -> None:
    source, a = Node('source', context=context), Node('a', context=context)
    got_a: list[Image] = []
    sub = in_process.Subscription(a, Image, TOPIC, got_a.append, common.RELIABLE)  # noqa: F841
    pub = in_process.Publisher(source, Image, TOPIC, common.RELIABLE)
    with _subscriber_elsewhere(context) as (got_other, spin_other):
        executor = common.single_threaded_executor(context)
        for node in (source, a):
            executor.add_node(node)
        assert spin_until(executor, lambda: spin_other() or pub.dds.get_subscription_count() == 2)
        for k in range(10):
            pub.publish(_frame(k))
        assert spin_until(executor, lambda: spin_other() or (len(got_a) == 10 and
                                                             len(got_other) == 10))
        spin_until(executor, spin_other, 0.3)  # nothing more comes
        assert pub.through_dds and pub.handed == 0
        assert _stamps(got_a) == _stamps(got_other) == list(range(1, 11))
        executor.shutdown()


def test_a_subscriber_elsewhere_matching_mid_run_switches_to_dds_in_order(context) -> None:
    source, a = Node('source', context=context), Node('a', context=context)
    got_a: list[Image] = []
    sub = in_process.Subscription(a, Image, TOPIC, got_a.append, common.RELIABLE)  # noqa: F841
    pub = in_process.Publisher(source, Image, TOPIC, common.RELIABLE)
    executor = common.single_threaded_executor(context)
    for node in (source, a):
        executor.add_node(node)
    for k in range(5):
        pub.publish(_frame(k))
    assert pub.handed == 5
    with _subscriber_elsewhere(context) as (got_other, spin_other):
        assert spin_until(executor, lambda: spin_other() or pub.dds.get_subscription_count() == 2)
        for k in range(5, 10):
            pub.publish(_frame(k))
        assert spin_until(executor, lambda: spin_other() or (len(got_a) == 10 and
                                                             len(got_other) == 5))
        spin_until(executor, spin_other, 0.3)  # nothing more comes
        assert pub.through_dds and pub.handed == 5
        assert _stamps(got_a) == list(range(1, 11))  # each once, in order across the switch
        assert _stamps(got_other) == list(range(6, 11))
    executor.shutdown()


def test_a_destroyed_nodes_subscription_does_not_hide_a_subscriber_elsewhere(context) -> None:
    source, gone = Node('source', context=context), Node('gone', context=context)
    kept = in_process.Subscription(gone, Image, TOPIC, lambda _: None,  # noqa: F841
                                   common.RELIABLE)
    gone.destroy_node()  # still referenced: the registry's weak reference stays alive
    pub = in_process.Publisher(source, Image, TOPIC, common.RELIABLE)
    with _subscriber_elsewhere(context) as (got_other, spin_other):
        executor = common.single_threaded_executor(context)
        executor.add_node(source)
        assert spin_until(executor, lambda: spin_other() or pub.dds.get_subscription_count() == 1)
        for k in range(3):
            pub.publish(_frame(k))
        assert spin_until(executor, lambda: spin_other() or len(got_other) == 3)
        assert pub.handed == 0
        executor.shutdown()


def test_a_node_behind_takes_one_handed_frame_per_task(context) -> None:
    source, a = Node('source', context=context), Node('a', context=context)
    got: list[Image] = []
    sub = in_process.Subscription(a, Image, TOPIC, got.append, common.RELIABLE)  # noqa: F841
    pub = in_process.Publisher(source, Image, TOPIC, common.RELIABLE)
    for k in range(2):  # handed before the node spins anywhere: delivered once it does
        pub.publish(_frame(k))
    executor = SingleThreadedExecutor(context=context)
    for node in (source, a):
        executor.add_node(node)
    for k in range(2, 6):
        pub.publish(_frame(k))
    seen = []
    for _ in range(6):  # a backlog is taken between the node's other callbacks
        executor.spin_once(timeout_sec=1.0)
        seen.append(len(got))
    assert seen == [1, 2, 3, 4, 5, 6]
    assert _stamps(got) == list(range(1, 7))
    executor.shutdown()


def test_a_subscription_that_keeps_the_last_n_drops_the_oldest(context) -> None:
    source, a = Node('source', context=context), Node('a', context=context)
    got: list[Image] = []
    keep_3 = QoSProfile(depth=3, reliability=ReliabilityPolicy.RELIABLE,
                        history=HistoryPolicy.KEEP_LAST)
    sub = in_process.Subscription(a, Image, TOPIC, got.append, keep_3)  # noqa: F841
    pub = in_process.Publisher(source, Image, TOPIC, common.RELIABLE)
    executor = common.single_threaded_executor(context)
    for node in (source, a):
        executor.add_node(node)
    for k in range(8):  # nothing spins meanwhile: a node behind (live)
        pub.publish(_frame(k))
    spin_until(executor, lambda: False, 0.3)
    assert _stamps(got) == [6, 7, 8]
    executor.shutdown()
