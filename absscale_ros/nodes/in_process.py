"""
Messages between nodes of one process handed over as they are, not through DDS.

rclpy has no intra-process transport: a decoded 1280x720 frame published to the detector and
the keyframe selector beside it was serialised once and taken and deserialised by each, ~1.5 ms
of CPU a frame more than making the message (2.1 against 0.56 ms, a publisher with two such
subscriptions against none, `absscale_ros` frames on one EventsExecutor). ``Publisher`` hands
the message object to the ``Subscription``s of its topic in the same rclpy context instead,
when they are all the topic has: each still has its DDS subscription, so discovery, the lossless
replay's acknowledgements (who owes one for a frame) and a recorder see the same graph. Once a
subscriber in another process (or a recorder) matched, every message goes through DDS, and
only there, for the rest of the run: none is delivered twice or out of order.

A handed message is delivered on its subscription's executor, as a DDS message would be: the
publisher (the frame decoder's worker thread) queues it and gives the executor a task that
delivers what is queued (``Executor.create_task``, which any thread may call; the events
executor has no guard conditions). The queue keeps the subscription's history depth: live, a
node that is behind drops the oldest frames as it did. A message handed before the node is
added to an executor waits for the next one. A task belongs to no callback group: on a
multi-threaded executor it could run beside the node's other callbacks (every node that
subscribes this way spins on a single-threaded one).
Subscribers share the message: they must not write into it (none does; they read frames).
"""
from collections import deque
import threading
from typing import Any, Callable
import weakref

from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile

# rclpy context -> topic -> its in-process subscriptions, all weakly (a strong reference to a
# subscription would keep its node and so the context key alive: every run's nodes would stay).
_BY_CONTEXT: 'weakref.WeakKeyDictionary[Any, dict[str, list[weakref.ref[Subscription]]]]' = \
    weakref.WeakKeyDictionary()
_REGISTRY_LOCK = threading.Lock()


def _subscriptions(node: Node, topic: str) -> list['weakref.ref[Subscription]']:
    with _REGISTRY_LOCK:
        return _BY_CONTEXT.setdefault(node.context, {}).setdefault(topic, [])


class Subscription:
    """
    A node's subscription that also takes messages handed over in this process (see
    ``Publisher``); ``callback`` runs on the node's executor either way. The node keeps it:
    the registry holds it weakly, so a dropped one takes only DDS messages.
    """

    def __init__(self, node: Node, msg_type: Any, topic: str, callback: Callable[[Any], None],
                 qos: QoSProfile, **kwargs: Any) -> None:
        self.dds = node.create_subscription(msg_type, topic, callback, qos, **kwargs)
        self.topic_name, self.msg_type = self.dds.topic_name, msg_type
        self._callback = callback
        keep = qos.depth if qos.history == HistoryPolicy.KEEP_LAST else None
        self._queue: deque[Any] = deque(maxlen=keep)
        self._lock = threading.Lock()
        self._node = node
        _subscriptions(node, self.topic_name).append(weakref.ref(self))

    def hand(self, msg: Any) -> None:
        """Queue ``msg`` for the callback on the node's executor (from any thread)."""
        with self._lock:
            self._queue.append(msg)
        executor = self._node.executor
        if executor is not None:  # one task per message: a task finds it, or an earlier one
            try:
                executor.create_task(self._deliver)
            except (AttributeError, RuntimeError):
                # a shut-down executor (the classic one has lost its guard condition): the
                # message is dropped, as DDS would drop it for a node no longer spinning
                with self._lock:
                    self._queue.clear()

    def _deliver(self) -> None:
        while True:
            with self._lock:
                if not self._queue:
                    return
                msg = self._queue.popleft()
            self._callback(msg)


class Publisher:
    """
    A node's publisher that hands each message to the ``Subscription``s of its topic in this
    process while no other subscriber matched (see the module's docstring).
    """

    def __init__(self, node: Node, msg_type: Any, topic: str, qos: QoSProfile) -> None:
        self.dds = node.create_publisher(msg_type, topic, qos)
        self.topic_name, self._msg_type = self.dds.topic_name, msg_type
        self._local = _subscriptions(node, self.topic_name)
        self.through_dds = False  # once True, for good
        self.handed = 0  # messages handed over in this process

    def publish(self, msg: Any) -> None:
        local = [s for ref in self._local
                 if (s := ref()) is not None and s.msg_type is self._msg_type]
        if not self.through_dds and local:
            if self.dds.get_subscription_count() <= len(local):
                for sub in local:
                    sub.hand(msg)
                self.handed += 1
                return
            self.through_dds = True  # a subscriber elsewhere matched: DDS only from now on
        self.dds.publish(msg)
