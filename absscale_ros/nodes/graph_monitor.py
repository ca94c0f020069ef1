"""
graph_monitor: counts every message on the graph's topics and keeps the latest diagnostics.

``absscale run`` reads it to write report.json; it does not acknowledge, so it never slows the
lossless replay down. Decoded images (``sensor_msgs/Image``, 2.7 MB a 1280x720 frame) are
counted from the step acknowledgements that announce them instead of being received, unless
they are recorded: taking every frame had cost a runner with its nodes in other processes
about 2 ms of CPU a frame. Their bytes are then not counted.
"""
import time
from typing import Any

from absscale_ros import bagio, conversions
from absscale_ros.core import replay
from absscale_ros.core.errors import AbsScaleError
from absscale_ros.nodes import common
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.serialization import deserialize_message, serialize_message
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Header

WATCHED_PREFIXES = ('/absscale/', '/scaled_cloud')
VERTICES_TOPIC = '/absscale/vertices'
LATCHED_TOPICS = ('/scaled_cloud', '/absscale/scaled_path', '/absscale/scale',
                  '/absscale/sparse_cloud_metric')
LATE_JOINER = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
# The last message of these is kept for the run's output files.
KEPT_TOPICS = ('/scaled_cloud', '/absscale/sparse_cloud', '/absscale/keyframe_path',
               '/absscale/scaled_path', '/absscale/scale', '/absscale/sparse_cloud_metric')


class GraphMonitorNode(Node):

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('graph_monitor', **kwargs)
        self.counts: dict[str, int] = {}
        self.bytes: dict[str, int] = {}
        self.diagnostics: dict[str, dict[str, Any]] = {}
        self._subs: dict[str, Any] = {}
        self.latest: dict[str, tuple[Any, bytes]] = {}  # topic -> (message class, CDR bytes)
        self._types: dict[str, str] = {}
        self.detections: list[tuple[int, int]] = []  # (stamp_ns, vertices) per frame
        self.cloud_updates: list[tuple[int, int]] = []  # /scaled_cloud (stamp, monotonic ns)
        self.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics,
                                 common.RELIABLE)
        self._recorder: Any = None
        self._not_recorded: set[str] = set()
        self.announced: set[str] = set()  # image topics counted from acknowledgements
        self.create_subscription(Header, common.ACK_TOPIC, self._on_ack, common.RELIABLE)
        self.discover()
        self.create_timer(0.2, self.discover)

    def record(self, path: str) -> None:
        """Write every graph topic (not the bag's own) to an MCAP file, for Foxglove."""
        self._recorder = bagio.BagWriter(path).__enter__()
        self.announced.clear()  # recorded images must be received
        self.discover()

    def watch(self, topic: str, msgtype: str, recorded: bool = True,
              best_effort: bool = False) -> None:
        """Count ``topic`` from now on (the runner names the bag's topics before replay)."""
        if not recorded:
            self._not_recorded.add(topic)
        if topic not in self._subs:
            cls = common.message_class(msgtype)
            self._types[topic] = msgtype
            # Latched outputs only accept subscribers that ask for TRANSIENT_LOCAL; asking it
            # of a volatile publisher would match nothing.
            qos = LATE_JOINER if topic in LATCHED_TOPICS else common.RELIABLE
            if best_effort:  # a reliable request would not match a sensor-data publisher
                qos = common.SENSOR
            self._subs[topic] = self.create_subscription(
                cls, topic, lambda data, t=topic, c=cls: self._count(t, data, c), qos, raw=True)

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def discover(self) -> None:
        """Subscribe to each new watched topic, whatever its type."""
        for topic, types in self.get_topic_names_and_types():
            # Subscribing to a debug overlay would make its node draw it for nobody.
            if topic in self._subs or topic == common.ACK_TOPIC or 'debug' in topic:
                continue
            if not topic.startswith(WATCHED_PREFIXES) or len(types) != 1:
                continue
            if types[0] == common.ANNOUNCED_IMAGE_TYPE and self._recorder is None:
                self.announced.add(topic)
                continue
            try:
                self.watch(topic, types[0])
            except AbsScaleError:  # a type this process cannot load: not ours to count
                continue

    def _count(self, topic: str, data: bytes, cls: Any = None) -> None:
        self.counts[topic] = self.counts.get(topic, 0) + 1
        if topic in KEPT_TOPICS:
            self.latest[topic] = (cls, data)
        if self._recorder is not None and topic not in self._not_recorded:
            # Receive time as log time, as `ros2 bag record` does: one clock for all topics.
            self._recorder.write(topic, self._types[topic], time.time_ns(), data)
        if topic == '/scaled_cloud':
            stamp = bagio.header_stamp_ns(data)
            if stamp is not None:
                self.cloud_updates.append((stamp, time.monotonic_ns()))
        if topic == VERTICES_TOPIC:
            self.detections.append(conversions.cloud_stamp_and_size(deserialize_message(data,
                                                                                        cls)))
        self.bytes[topic] = self.bytes.get(topic, 0) + len(data)

    def _on_ack(self, msg: Header) -> None:
        if not self.announced:
            return
        try:
            outputs = replay.Ack.decode(*conversions.ack_from_msg(msg)).outputs
        except ValueError:
            return  # bag_replay reports malformed acknowledgements
        for topic in outputs:
            if topic in self.announced:
                self.counts[topic] = self.counts.get(topic, 0) + 1

    def close(self) -> None:
        """Finish the recording, if any."""
        if self._recorder is not None:
            self._recorder.__exit__(None, None, None)
            self._recorder = None

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        self.counts['/diagnostics'] = self.counts.get('/diagnostics', 0) + 1
        if self._recorder is not None:
            self._recorder.write('/diagnostics', 'diagnostic_msgs/msg/DiagnosticArray',
                                 time.time_ns(), serialize_message(msg))
        self.diagnostics.update(conversions.diagnostic_summary(msg))

    def report(self) -> dict[str, Any]:
        return {'messages_per_topic': dict(sorted(self.counts.items())),
                'bytes_per_topic': dict(sorted(self.bytes.items())),
                'diagnostics': self.diagnostics}


def main(args: list[str] | None = None) -> None:
    common.run_node(GraphMonitorNode, args)
