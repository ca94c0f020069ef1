"""in_process: messages handed to subscriptions of the same process, or through DDS."""
import threading

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


def test_a_subscriber_elsewhere_gets_every_frame_through_dds_and_none_twice(context) -> None:
    source, a = Node('source', context=context), Node('a', context=context)
    got_a: list[Image] = []
    got_other: list[Image] = []
    sub = in_process.Subscription(a, Image, TOPIC, got_a.append, common.RELIABLE)  # noqa: F841
    pub = in_process.Publisher(source, Image, TOPIC, common.RELIABLE)
    # Another process's subscriber: another context, another DDS participant.
    other_context = rclpy.Context()
    rclpy.init(context=other_context, domain_id=context.get_domain_id())
    try:
        other = Node('other', context=other_context)
        other.create_subscription(Image, TOPIC, got_other.append, common.RELIABLE)
        executor = common.single_threaded_executor(context)
        other_executor = common.single_threaded_executor(other_context)
        for node in (source, a):
            executor.add_node(node)
        other_executor.add_node(other)

        def spin_both() -> bool:
            other_executor.spin_once(timeout_sec=0.01)
            return False
        assert spin_until(executor, lambda: spin_both() or pub.dds.get_subscription_count() == 2)
        for k in range(10):
            pub.publish(_frame(k))
        assert spin_until(executor, lambda: spin_both() or (len(got_a) == 10 and
                                                            len(got_other) == 10))
        spin_until(executor, lambda: spin_both(), 0.3)  # nothing more comes
        assert pub.through_dds and pub.handed == 0
        assert _stamps(got_a) == _stamps(got_other) == list(range(1, 11))
        executor.shutdown()
        other_executor.shutdown()
    finally:
        rclpy.try_shutdown(context=other_context)


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
