"""
The sfm node's message plumbing: its three keyframe inputs paired by stamp (every input that
never pairs acknowledged, so a lossless replay goes on), the queue of keyframes mapped on the
executor's thread, and the map's output messages.
"""
from collections import deque
from concurrent.futures import Future
from typing import Any, Callable

from absscale_ros import conversions
from absscale_ros.core import pairing, replay, sfm_outputs, sfm_session
from absscale_ros.nodes import common
from geometry_msgs.msg import TransformStamped
from rclpy.node import Node
from sensor_msgs.msg import Image, PointCloud2

Item = tuple[Image, PointCloud2, TransformStamped | None]
# How often the executor queue looks whether its oldest keyframe's features are detected,
# while it holds one (the feature worker cannot wake the events executor: no guard conditions).
READY_PERIOD_S = 0.002


class KeyframeInputs:
    """
    Subscribes ``/absscale/keyframes``, ``/absscale/keyframe_vertices`` and, with
    ``use_tracked_steps``, ``/absscale/keyframe_motion``; pairs them by stamp.

    :param on_image: called with (stamp_ns, image) as a keyframe's image arrives.
    :param handle: called with each paired keyframe; returns the topics it published (its
        inputs are then acknowledged; ``replay.DEFERRED`` if queued, see ``ack_deferred``), or
        None (the live worker has it: no acknowledgement).
    :param count: counts keyframes that never reach the map ('unpaired', 'no_tracked_step').
    """

    def __init__(self, node: Node, group: Any, depth: int, use_tracked_steps: bool,
                 on_image: Callable[[int, Image], None],
                 handle: Callable[[Item], list[str] | None],
                 count: Callable[[str], None]) -> None:
        self._on_image, self._handle, self._count = on_image, handle, count
        self._ack = common.StepAck(node)
        self._pairer: pairing.StampPairer[Image, PointCloud2] = pairing.StampPairer(depth)
        self._step_pairer: pairing.StampPairer[tuple[Image, PointCloud2], TransformStamped] = \
            pairing.StampPairer(depth)
        self._kf_sub = node.create_subscription(
            Image, '/absscale/keyframes', self._on_keyframe, common.RELIABLE,
            callback_group=group)  # live too: LiveUpdates drops, knowing what it skipped
        self._kv_sub = node.create_subscription(
            PointCloud2, '/absscale/keyframe_vertices', lambda m: self._settle(
                self._pairer.add_second(conversions.stamp_to_ns(m.header.stamp), m)),
            common.RELIABLE, callback_group=group)
        self._motion_sub = node.create_subscription(
            TransformStamped, '/absscale/keyframe_motion', lambda m: self._settle_steps(
                self._step_pairer.add_second(conversions.stamp_to_ns(m.header.stamp), m)),
            common.RELIABLE, callback_group=group) if use_tracked_steps else None

    def _on_keyframe(self, msg: Image) -> None:
        stamp_ns = conversions.stamp_to_ns(msg.header.stamp)
        self._on_image(stamp_ns, msg)
        self._settle(self._pairer.add_first(stamp_ns, msg))

    def _settle(self, result: pairing.Pairing[Image, PointCloud2]) -> None:
        for stamp_ns, image, vertices in result.pairs:
            if self._motion_sub is not None:
                self._settle_steps(self._step_pairer.add_first(stamp_ns, (image, vertices)))
            else:
                self._done(image, vertices, None)
        for _, msg in result.dropped_first:
            self._count('unpaired')
            self._ack.ack(msg.header.stamp, self._kf_sub.topic_name)
        for _, msg in result.dropped_second:
            self._ack.ack(msg.header.stamp, self._kv_sub.topic_name)

    def _settle_steps(self, result: pairing.Pairing[tuple[Image, PointCloud2],
                                                    TransformStamped]) -> None:
        # A keyframe whose step never came is older than the pairs just made: first, unchecked.
        for _, (image, vertices) in result.dropped_first:
            self._count('no_tracked_step')
            self._done(image, vertices, None)
        for _, (image, vertices), motion in result.pairs:
            self._done(image, vertices, motion)
        for _, motion in result.dropped_second:
            self._ack.ack(motion.header.stamp, self._motion_sub.topic_name)

    def _done(self, image: Image, vertices: PointCloud2,
              motion: TransformStamped | None) -> None:
        outputs = self._handle((image, vertices, motion))
        if outputs is None:
            return
        self._ack.ack(image.header.stamp, self._kf_sub.topic_name, outputs)
        self._ack.ack(vertices.header.stamp, self._kv_sub.topic_name, outputs)
        if motion is not None:
            self._ack.ack(motion.header.stamp, self._motion_sub.topic_name, outputs)

    def ack_deferred(self, stamp: Any, outputs: list[str]) -> None:
        """A queued keyframe's second acknowledgement: the topics published for it (its
        inputs were acknowledged with ``replay.DEFERRED``)."""
        self._ack.ack(stamp, replay.DEFERRED, outputs)


class ExecutorQueue:
    """
    Calls run in order on the executor's thread, each once its ``ready`` future (a keyframe's
    features, detected ahead on the feature worker) is done; the futures they return hold
    their results or exceptions, as a worker's would. In one process (the runner) a keyframe
    mapped at once waited there for its features (~85 ms of SIFT on the 60 s bag, the frame
    nodes idle meanwhile); queued, the frames after it go on while they are detected. A worker
    thread for the mapping itself would only contend with the frame nodes for the GIL.
    """

    def __init__(self, node: Node, group: Any) -> None:
        self._items: deque[tuple[Future[Any], Future[Any] | None, Callable[..., Any],
                                 tuple[Any, ...]]] = deque()
        self._timer = node.create_timer(READY_PERIOD_S, self._run_ready, callback_group=group)
        self._timer.cancel()

    def submit(self, ready: 'Future[Any] | None', fn: Callable[..., Any],
               *args: Any) -> 'Future[Any]':
        """Run ``fn(*args)`` after the calls before it, once ``ready`` (if any) is done."""
        done: Future[Any] = Future()
        self._items.append((done, ready, fn, args))
        if self._timer.is_canceled():
            self._timer.reset()
        return done

    def run_through(self, done: 'Future[Any]') -> None:
        """Run the queued calls up to the one of ``done`` now, ready or not."""
        while not done.done() and self._items:
            self._run_one()

    def _run_ready(self) -> None:
        while self._items and (self._items[0][1] is None or self._items[0][1].done()):
            self._run_one()
        if not self._items:
            self._timer.cancel()

    def _run_one(self) -> None:
        done, _, fn, args = self._items.popleft()
        try:
            done.set_result(fn(*args))
        except Exception as err:  # noqa: BLE001 - raised where the result is asked for
            done.set_exception(err)


def map_messages(session: sfm_session.SfmSession, stamp_ns: int,
                 frame: str) -> tuple[dict[str, Any], int]:
    """
    The published segment's messages by topic name (``target_points`` last: the scale node
    reads the cloud and path then), and its target vertex count.
    """
    assert session.engine is not None
    m = sfm_outputs.best_segment(session.engine).map
    xyz, rgb = sfm_outputs.cloud(m, session.engine.K, session.cfg.cloud_cfg)
    stamps, poses = sfm_outputs.path(m)
    tp = sfm_outputs.target_points(m, session.cfg.vertex_cfg.publish_min_angle_deg)
    return {'sparse_cloud': conversions.xyz_rgb_to_cloud_msg(xyz, rgb, stamp_ns, frame),
            'keyframe_path': conversions.poses_to_path_msg(poses, stamps, frame, stamp_ns),
            'target_points': conversions.xyz_rgb_to_cloud_msg(
                tp.points, None, stamp_ns, frame, extra={
                    'object_id': tp.object_ids, 'vertex_id': tp.vertex_ids,
                    'n_obs': tp.n_obs, 'angle_deg': tp.angle_deg,
                    'target_type': tp.target_types})}, len(tp.points)
