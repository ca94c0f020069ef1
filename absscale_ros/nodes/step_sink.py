"""
step_sink: a consumer that acknowledges every message, for replay tests and benchmarks.

It subscribes to one topic of any type, keeps each message's serialized bytes if asked
(``keep_bytes``) and acknowledges it, so ``bag_replay`` in step mode can measure the graph.
"""
from typing import Any

from absscale_ros.nodes import common
from rclpy.node import Node
from rclpy.serialization import deserialize_message


class StepSinkNode(Node):

    def __init__(self, name: str = 'step_sink', **kwargs: Any) -> None:
        super().__init__(name, **kwargs)
        p = self.declare_parameters('', [('topic', '/camera/image_raw/compressed'),
                                         ('msgtype', 'sensor_msgs/msg/CompressedImage'),
                                         ('keep_bytes', False)])
        topic, msgtype, self._keep = (x.value for x in p)
        self._type = common.message_class(msgtype)
        self._ack = common.StepAck(self)
        self.received: list[bytes] = []
        self.count = 0
        # raw=True hands us the CDR bytes, so tests can check they arrive unchanged.
        self._sub = self.create_subscription(self._type, topic, self._on_msg, common.RELIABLE,
                                             raw=True)

    def _on_msg(self, data: bytes) -> None:
        msg = deserialize_message(data, self._type)  # the cost a real consumer pays
        self.count += 1
        if self._keep:
            self.received.append(bytes(data))
        self._ack.ack(msg.header.stamp, self._sub.topic_name)


def main(args: list[str] | None = None) -> None:
    common.run_node(StepSinkNode, args)
