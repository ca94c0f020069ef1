"""
graph_monitor: counts every message on the graph's topics and keeps the latest diagnostics.

``absscale run`` reads it to write report.json; it does not acknowledge, so it never slows the
lossless replay down.
"""
from typing import Any

from absscale_ros import conversions
from absscale_ros.core.errors import AbsScaleError
from absscale_ros.nodes import common
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node

WATCHED_PREFIXES = ('/absscale/', '/scaled_cloud')


class GraphMonitorNode(Node):

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('graph_monitor', **kwargs)
        self.counts: dict[str, int] = {}
        self.bytes: dict[str, int] = {}
        self.diagnostics: dict[str, dict[str, Any]] = {}
        self._subs: dict[str, Any] = {}
        self.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics,
                                 common.RELIABLE)
        self._discover()
        self.create_timer(0.2, self._discover)

    def watch(self, topic: str, msgtype: str) -> None:
        """Count ``topic`` from now on (the runner names the bag's topics before replay)."""
        if topic not in self._subs:
            self._subs[topic] = self.create_subscription(
                common.message_class(msgtype), topic,
                lambda data, t=topic: self._count(t, data), common.RELIABLE, raw=True)

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def _discover(self) -> None:
        """Subscribe to each new watched topic, whatever its type."""
        for topic, types in self.get_topic_names_and_types():
            if topic in self._subs or topic == common.ACK_TOPIC:
                continue
            if not topic.startswith(WATCHED_PREFIXES) or len(types) != 1:
                continue
            try:
                self.watch(topic, types[0])
            except AbsScaleError:  # a type this process cannot load: not ours to count
                continue

    def _count(self, topic: str, data: bytes) -> None:
        self.counts[topic] = self.counts.get(topic, 0) + 1
        self.bytes[topic] = self.bytes.get(topic, 0) + len(data)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        self._count('/diagnostics', b'')
        for status in msg.status:
            self.diagnostics[status.name] = {
                'level': int.from_bytes(status.level, 'little') if isinstance(
                    status.level, bytes) else int(status.level),
                'message': status.message, 'values': conversions.diagnostic_values(status)}

    def report(self) -> dict[str, Any]:
        return {'messages_per_topic': dict(sorted(self.counts.items())),
                'bytes_per_topic': dict(sorted(self.bytes.items())),
                'diagnostics': self.diagnostics}


def main(args: list[str] | None = None) -> None:
    common.run_node(GraphMonitorNode, args)
