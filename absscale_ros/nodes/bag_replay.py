"""
bag_replay: publish a bag's topics with their original types and bytes.

Modes: ``rate`` (bag timing times ``rate``), ``fast`` (as fast as possible, may overrun slow
subscribers), ``step`` (lossless: the next stepped message goes out only when every
acknowledging node downstream has handled the previous one; see core/replay.py). In step mode,
once every frame is acknowledged, one more step goes out on ``end_topic`` (std_msgs/Header
stamped after the last frame): nodes that keep state to the end (the sfm's final batch
adjustment) answer it with their last outputs, and the replay is drained when those are
acknowledged too (at most ``end_timeout_s``).
"""
import time
from typing import Any, Callable

from absscale_ros import bagio, conversions
from absscale_ros.core import replay
from absscale_ros.core.errors import BagError
from absscale_ros.nodes import common
from rclpy.node import Node
from std_msgs.msg import Header

# What rclpy reports for an endpoint whose node's name has not been discovered yet.
UNKNOWN_NODE = '_NODE_NAME_UNKNOWN_'
IMAGE_TYPES = ('sensor_msgs/msg/Image', 'sensor_msgs/msg/CompressedImage')
# Rate and fast modes keep time with a 1 ms tick. Step mode is driven by acknowledgements: its
# tick only starts the replay and expires steps, and at 1 kHz it had cost a --processes
# runner more CPU than reading and publishing the bag.
TICK_S = {'rate': 0.001, 'fast': 0.001, 'step': 0.02}
# Before the replay starts, the graph is queried this often: each query walks every endpoint
# of every topic (~0.3 ms), and node processes are still starting on the same cores.
READY_PERIOD_S = 0.05


class BagReplayNode(Node):

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('bag_replay', **kwargs)
        p = self.declare_parameters('', [
            ('bag', ''), ('mode', 'rate'), ('rate', 1.0), ('topics', ''), ('remap', ''),
            ('start_offset_s', 0.0), ('loop', False), ('step_topics', ''),
            ('step_timeout_s', 10.0), ('expect_nodes', ''), ('qos', 'reliable'),
            ('progress_period_s', 5.0), ('startup_timeout_s', 5.0), ('settle_s', 0.0),
            ('observer', ''), ('observer_images', True), ('step_window', 1),
            ('end_topic', common.END_OF_BAG_TOPIC), ('end_timeout_s', 300.0)])
        self._p = {x.name: x.value for x in p}
        if self._p['mode'] not in ('rate', 'fast', 'step'):
            raise ValueError(f"mode must be rate, fast or step, not {self._p['mode']!r}")
        self._bag = bagio.open_bag(self._p['bag'])
        wanted = _csv(self._p['topics']) or list(self._bag.topics)
        self._infos = {t: i for t, i in self._bag.topics.items() if t in wanted}
        remap = dict(r.split(':=') for r in _csv(self._p['remap']))
        qos = common.SENSOR if self._p['qos'] == 'sensor_data' else common.RELIABLE
        self._pubs = {t: self.create_publisher(self._class(t, i.msgtype), remap.get(t, t), qos)
                      for t, i in self._infos.items()}
        self._stepped = set(_csv(self._p['step_topics'])) or {
            t for t, i in self._infos.items() if i.msgtype in IMAGE_TYPES}
        self._window = replay.StepWindow(self._consumers_of, int(self._p['step_window']))
        stepped_end = self._p['mode'] == 'step' and bool(self._p['end_topic'])
        self._end_pub = self.create_publisher(Header, self._p['end_topic'], common.RELIABLE) \
            if stepped_end else None
        self._end = replay.StepWindow(self._consumers_of)  # the end-of-bag step
        self._end_sent = not stepped_end
        self._last_stamp = 0
        self._consumers: dict[str, list[str]] = {}
        self.total = sum(i.count for i in self._infos.values())
        self.published = self.steps = self.timeouts = 0
        self.finished = False
        self.published_at: dict[int, int] = {}  # frame stamp -> monotonic ns it went out
        self._known_since: float | None = None
        self._cursor: bagio.ReplayCursor | None = None
        self._last_progress = self._created = time.monotonic()
        self._ready_checked = -READY_PERIOD_S
        # The runner's own last condition (absscale run across processes: every endpoint
        # matched), checked once the graph is known.
        self.gate: Callable[[], bool] = lambda: True
        self._create_ack_sub()
        self._timer = self.create_timer(TICK_S[self._p['mode']], self._tick)

    def _class(self, topic: str, msgtype: str) -> Any:
        try:
            return common.message_class(msgtype)
        except BagError as err:
            raise BagError(f'{self._p["bag"]}: topic {topic}: {err}; leave it out with the '
                           'topics parameter') from err

    def topic_types(self) -> dict[str, str]:
        """Published topic (after remapping) -> message type."""
        return {self._pubs[t].topic_name: i.msgtype for t, i in self._infos.items()}

    def _create_ack_sub(self) -> None:
        self.create_subscription(Header, common.ACK_TOPIC, self._on_ack, common.RELIABLE)

    def _consumers_of(self, topic: str) -> list[str]:
        if topic not in self._consumers:
            ackers = {i.node_name for i in self.get_publishers_info_by_topic(common.ACK_TOPIC)}
            names = [i.node_name for i in self.get_subscriptions_info_by_topic(topic)]
            found = [n for n in names if n in ackers and n != UNKNOWN_NODE]
            if UNKNOWN_NODE in names:  # discovery still running: do not remember a partial answer
                return found
            self._consumers[topic] = found
        return self._consumers[topic]

    def _graph_known(self) -> bool:
        """True once discovery has named every endpoint of every topic (see UNKNOWN_NODE)."""
        for topic, _ in self.get_topic_names_and_types():
            for info in (*self.get_subscriptions_info_by_topic(topic),
                         *self.get_publishers_info_by_topic(topic)):
                if info.node_name == UNKNOWN_NODE:
                    return False
        return True

    def _observed(self) -> bool:
        """
        With ``observer`` set (absscale run's graph_monitor), it must hear every graph topic:
        without ``observer_images`` the acknowledgements instead of the image topics (a
        monitor that does not record counts images from them).
        """
        observer = self._p['observer']
        if not observer:
            return True
        images = self._p['observer_images']
        for topic, types in self.get_topic_names_and_types():
            if not topic.startswith('/absscale/') or 'debug' in topic:
                continue
            if images and topic == common.ACK_TOPIC:
                continue  # it hears the images themselves
            if not images and common.ANNOUNCED_IMAGE_TYPE in types:
                continue  # it counts them from the acknowledgements
            if observer not in {i.node_name for i in self.get_subscriptions_info_by_topic(topic)}:
                return False
        return True

    def _ready(self) -> bool:
        """Replay starts once the expected nodes can acknowledge and every topic is heard."""
        ackers = {i.node_name for i in self.get_publishers_info_by_topic(common.ACK_TOPIC)}
        missing = set(_csv(self._p['expect_nodes'])) - ackers
        unheard = [t for t, pub in self._pubs.items() if pub.get_subscription_count() == 0]
        if not missing and not unheard and self._graph_known() and self._observed() and \
                self.gate():
            # Across processes a publisher may be matched to its subscribers a moment after
            # discovery names them; a message sent before would be lost.
            if self._known_since is None:
                self._known_since = time.monotonic()
            return time.monotonic() - self._known_since >= self._p['settle_s']
        if time.monotonic() - self._created < self._p['startup_timeout_s']:
            return False
        self.get_logger().warning(f'starting without nodes {sorted(missing)} and with no '
                                  f'subscriber on {unheard}')
        return True

    def _start(self) -> None:
        start = self._bag.start_ns + int(self._p['start_offset_s'] * 1e9)
        self._cursor = bagio.ReplayCursor(self._bag, self._infos, start, self._p['loop'])
        self._t0 = (start, time.monotonic_ns())
        self._loops_seen = 0

    def _tick(self) -> None:
        if self.drained:
            return
        if self._cursor is None:
            now = time.monotonic()
            if now - self._ready_checked < READY_PERIOD_S:
                return
            self._ready_checked = now
            if not self._ready():
                return
            self._start()
        if self._p['mode'] == 'step':
            self._check_step_timeout()
            self._advance_step()
        else:
            self._publish_due()
        self._report_progress()

    def _publish_due(self) -> None:
        budget = 200  # yield to other callbacks between batches
        while budget and not self.finished:
            msg = self._cursor.peek() if self._cursor else None
            if msg is None:
                self._take()  # marks the replay finished
                return
            if self._cursor.loops != self._loops_seen:  # a new lap restarts the clock
                self._loops_seen = self._cursor.loops
                self._t0 = (self._t0[0], time.monotonic_ns())
            due = replay.due_wall_ns(msg.stamp_ns, self._t0[0], self._t0[1], self._p['rate'])
            if self._p['mode'] == 'rate' and due > time.monotonic_ns():
                return
            self._publish(self._take())
            budget -= 1

    @property
    def drained(self) -> bool:
        """Every message is out and (step mode) every step has been acknowledged, deferred
        acknowledgements and the end of the bag's included."""
        return self.finished and self._window.empty and self._end_sent and self._end.empty

    @property
    def steps_deferred(self) -> int:
        """Steps whose last acknowledgements a node deferred (queued work, see core/replay)."""
        return self._window.deferred_total

    def _advance_step(self) -> None:
        """Publish until the window of stepped messages in flight is full (or the bag ends)."""
        while not self.finished and not self._window.full:
            msg = self._take()
            if msg is None:
                return
            self._publish(msg)
            if msg.topic in self._stepped:
                stamp = bagio.header_stamp_ns(msg.data)
                stamp = msg.stamp_ns if stamp is None else stamp
                self._window.start(self._pubs[msg.topic].topic_name, stamp, time.monotonic())
                self.published_at[stamp] = time.monotonic_ns()
                self._last_stamp = max(self._last_stamp, stamp)
                self.steps += 1
        if self.finished and self._window.empty and not self._end_sent:
            self._send_end()

    def _send_end(self) -> None:
        """The end-of-bag step, stamped after every frame (answered by whoever subscribes)."""
        assert self._end_pub is not None
        self._end_sent = True
        stamp = self._last_stamp + 1
        self._end_pub.publish(conversions.end_of_bag_msg(stamp))
        self._end.start(self._end_pub.topic_name, stamp, time.monotonic())

    def _on_ack(self, msg: Header) -> None:
        try:
            ack = replay.Ack.decode(*conversions.ack_from_msg(msg))
        except ValueError as err:
            self.get_logger().warning(str(err), throttle_duration_sec=5.0)
            return
        if self._window.on_ack(ack, time.monotonic()) and self._cursor is not None:
            self._advance_step()
        self._end.on_ack(ack, time.monotonic())

    def _check_step_timeout(self) -> None:
        now = time.monotonic()
        for what, window, timeout in (('frame', self._window, self._p['step_timeout_s']),
                                      ('end of bag', self._end, self._p['end_timeout_s'])):
            for stamp, pending in window.expire(now, timeout):
                self.timeouts += 1
                self.get_logger().warning(
                    f'{what} {stamp}: no acknowledgement from {", ".join(pending)} '
                    f'after {timeout} s; moving on')
                self._consumers.clear()  # the graph may have changed

    def _take(self) -> bagio.BagMessage | None:
        assert self._cursor is not None
        msg = self._cursor.take()
        if msg is None:
            self.finished = True
            self.get_logger().info(f'replay finished: {self.published} messages, '
                                   f'{self.steps} steps, {self.timeouts} step timeouts')
        return msg

    def _publish(self, msg: bagio.BagMessage) -> None:
        self._pubs[msg.topic].publish(msg.data)  # serialized bytes: no re-encoding
        self.published += 1
        if self._p['mode'] != 'step' and msg.topic in self._stepped:
            stamp = bagio.header_stamp_ns(msg.data)
            self.published_at[msg.stamp_ns if stamp is None else stamp] = time.monotonic_ns()

    def _report_progress(self) -> None:
        now = time.monotonic()
        if now - self._last_progress >= self._p['progress_period_s']:
            self._last_progress = now
            self.get_logger().info(f'replayed {self.published}/{self.total} messages')

    def destroy_node(self) -> None:
        self._bag.__exit__(None, None, None)
        super().destroy_node()


def _csv(text: str) -> list[str]:
    return [t.strip() for t in text.split(',') if t.strip()]


def main(args: list[str] | None = None) -> None:
    common.run_node(BagReplayNode, args)
