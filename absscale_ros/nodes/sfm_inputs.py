"""
The sfm node's message plumbing: its three keyframe inputs paired by stamp (every input that
never pairs acknowledged, so a lossless replay goes on), and the map's output messages.
"""
from typing import Any, Callable

from absscale_ros import conversions
from absscale_ros.core import pairing, replay, sfm_outputs, sfm_session
from absscale_ros.nodes import common
from geometry_msgs.msg import TransformStamped
from rclpy.node import Node
from sensor_msgs.msg import Image, PointCloud2

Item = tuple[Image, PointCloud2, TransformStamped | None]


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
