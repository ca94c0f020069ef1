"""
scale: the unscaled reconstruction in metres, from the calibration object's known lengths.

Subscribes ``/absscale/target_points`` (PointCloud2: x, y, z, object_id, vertex_id, n_obs,
angle_deg, target_type), ``/absscale/sparse_cloud`` and ``/absscale/keyframe_path``. Publishes,
reliable + TRANSIENT_LOCAL depth 1 so late subscribers get the latest at once:
``/scaled_cloud`` (every field of the sparse cloud, x y z in metres, frame ``map``),
``/absscale/scaled_path`` and ``/absscale/scale`` (Float64MultiArray labelled
``factor,sigma,ci_low,ci_high,edges,objects``). Nothing is published until the evidence
passes the gate of ``core/scale.py``; ``/diagnostics`` says why not.
"""
from typing import Any

from absscale_ros import conversions
from absscale_ros.core import scale, targets
from absscale_ros.core.errors import AbsScaleError
from absscale_ros.nodes import common
from nav_msgs.msg import Path
import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Float64MultiArray


class ScaleNode(Node):

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('scale', **kwargs)
        self._cfg = common.declare_config(self, scale.ScaleConfig())
        p = {x.name: x.value for x in self.declare_parameters('', [
            ('sheet', 'letter'), ('sheet_size_m', [0.0, 0.0]), ('cube_edge_m', 0.8),
            ('frame_id', 'map'), ('min_change', 0.001), ('require_path', False),
            ('cloud_topic', '/scaled_cloud'), ('qos', 'reliable'), ('in_order', False)])}
        custom = tuple(p['sheet_size_m']) if min(p['sheet_size_m']) > 0 else None
        # 'auto': letter or A4, whichever the reconstructed corners fit (a tie claims nothing);
        # `absscale run` and the launch file narrow it to the detector's one sheet
        # (params.scale_sheet: an A6 card has A4's shape).
        sizes = targets.sheet_sizes_m(p['sheet'], custom)
        self._sheet_m, self._sheet_alternatives = sizes[0], tuple(sizes[1:])
        self._cube_m = p['cube_edge_m']
        self._frame, self._min_change = p['frame_id'], p['min_change']
        self._require_path = p['require_path']  # estimate from targets + path of one stamp
        # /absscale/sparse_cloud_metric when the dense node publishes /scaled_cloud (issue 9)
        self._cloud_pub = self.create_publisher(PointCloud2, p['cloud_topic'], common.LATCHED)
        self._path_pub = self.create_publisher(Path, '/absscale/scaled_path', common.LATCHED)
        self._scale_pub = self.create_publisher(Float64MultiArray, '/absscale/scale',
                                                common.LATCHED)
        self._diag = common.DiagnosticsPublisher(self, 'metric scale')
        self._ack = common.StepAck(self)
        self.estimate: scale.ScaleEstimate | None = None
        self._published_factor: float | None = None
        self.history: list[dict[str, float]] = []
        self._cloud: Any = None
        self._path: Any = None
        self._targets: Any = None
        self._estimated_ns: int | None = None
        self._why_not = 'no target points yet'
        # Live, only the newest of each: a backlog would only delay the newest keyframe.
        live = p['qos'] == common.LIVE
        qos = common.live_input(1) if live else common.RELIABLE
        ordered = p['in_order'] and not live
        self._handlers = {'/absscale/sparse_cloud': self._on_cloud,  # the sfm's order
                          '/absscale/keyframe_path': self._on_path,
                          '/absscale/target_points': self._on_targets}
        self._arrived: dict[int, dict[str, Any]] = {}  # offline: stamp -> topic -> message
        for topic, cls in (('/absscale/target_points', PointCloud2),
                           ('/absscale/sparse_cloud', PointCloud2),
                           ('/absscale/keyframe_path', Path)):
            self.create_subscription(cls, topic, (lambda m, t=topic: self._handlers[t](m, t))
                                     if not ordered else
                                     (lambda m, t=topic: self._in_order(m, t)),
                                     qos)

    def _in_order(self, msg: Any, topic: str) -> None:
        """
        Offline with ``in_order`` (the sfm publishes all three per keyframe): handle a
        keyframe's three messages once all have come, in the order the sfm publishes them.
        Across processes they may arrive in another order (an sfm that queues keyframes
        publishes while this node works), and the cloud last published, scaled by the factor
        of the message before, would depend on it. A keyframe still missing one when a newer
        one is complete goes first with what it has.
        """
        stamp = conversions.stamp_to_ns(msg.header.stamp)
        self._arrived.setdefault(stamp, {})[topic] = msg
        if len(self._arrived[stamp]) < len(self._handlers):
            return
        for older in sorted(s for s in self._arrived if s <= stamp):
            got = self._arrived.pop(older)
            for t, handle in self._handlers.items():
                if t in got:
                    handle(got[t], t)

    def _on_targets(self, msg: PointCloud2, topic: str) -> None:
        self._targets = msg
        outputs = self._estimate_when_paired()
        self._ack.ack(msg.header.stamp, topic, outputs)

    def _on_cloud(self, msg: PointCloud2, topic: str) -> None:
        self._cloud = msg
        outputs = self._publish_all(msg.header.stamp) if self.estimate else []
        self._ack.ack(msg.header.stamp, topic, outputs)

    def _on_path(self, msg: Path, topic: str) -> None:
        self._path = msg
        outputs = self._estimate_when_paired()
        if self.estimate and not outputs:
            outputs = self._publish_all(msg.header.stamp)
        self._ack.ack(msg.header.stamp, topic, outputs)

    def _estimate_when_paired(self) -> list[str]:
        """
        Estimate once per target_points message, from it and the path of the same stamp.

        The sfm publishes both per keyframe, but on two topics whose arrival order is not
        fixed (least of all across processes); waiting for the pair keeps the verdict
        independent of it. Without ``require_path`` the path is optional (standalone use).
        """
        msg = self._targets
        if msg is None:
            return []
        stamp_ns = conversions.stamp_to_ns(msg.header.stamp)
        path_ns = None if self._path is None else conversions.stamp_to_ns(self._path.header.stamp)
        if stamp_ns == self._estimated_ns or (self._require_path and path_ns != stamp_ns):
            return []
        self._estimated_ns = stamp_ns
        path = None if path_ns != stamp_ns else conversions.path_msg_to_poses(self._path)
        outputs = self._estimate(msg, path)
        self._diagnose(msg.header.stamp)
        return outputs

    def _estimate(self, msg: PointCloud2, path: Any) -> list[str]:
        pts = conversions.cloud_msg_to_array(msg)
        xyz = np.stack([pts[a] for a in 'xyz'], axis=1).astype(np.float64) if len(pts) else \
            np.zeros((0, 3))
        objects = scale.group_objects(xyz, *(np.asarray(pts[f]) for f in (
            'object_id', 'target_type', 'n_obs', 'angle_deg')), self._sheet_m, self._cube_m,
            self._sheet_alternatives) \
            if len(pts) else []
        try:
            if path is not None:  # (N, 7) poses and (N,) stamps of the same keyframe
                scale.check_path(path[0][:, :3], np.asarray(path[1], np.int64), self._cfg)
            est = scale.estimate(objects, self._cfg, None if path is None else len(path[1]))
        except AbsScaleError as err:
            self._why_not = str(err)
            self.get_logger().info(f'no metric scale yet: {err}', throttle_duration_sec=10.0)
            return []
        # Against the factor last published, not the last estimate: small steps add up.
        changed = self._published_factor is None or \
            abs(est.factor / self._published_factor - 1.0) > self._min_change
        self.estimate = est
        self.history.append({'stamp_ns': conversions.stamp_to_ns(msg.header.stamp),
                             'factor': est.factor, 'sigma': est.sigma})
        return self._publish_all(msg.header.stamp) if changed else []

    def _publish_all(self, stamp: Any) -> list[str]:
        est = self.estimate
        assert est is not None
        stamp_ns = conversions.stamp_to_ns(stamp)
        self._published_factor = est.factor
        self._scale_pub.publish(conversions.scale_to_msg({
            'factor': est.factor, 'sigma': est.sigma, 'ci_low': est.interval[0],
            'ci_high': est.interval[1], 'edges': len(est.measured), 'objects': est.objects_used}))
        outputs = ['/absscale/scale']
        if self._cloud is not None:
            self._cloud_pub.publish(conversions.scaled_cloud_msg(self._cloud, est.factor,
                                                                 stamp_ns, self._frame))
            outputs.append(self._cloud_pub.topic_name)
        if self._path is not None:
            poses, stamps = conversions.path_msg_to_poses(self._path)
            self._path_pub.publish(conversions.poses_to_path_msg(
                scale.apply_to_positions(poses, est.factor), stamps, self._frame, stamp_ns))
            outputs.append('/absscale/scaled_path')
        return outputs

    def _diagnose(self, stamp: Any) -> None:
        est = self.estimate
        values: dict[str, object] = {'observable': est is not None}
        if est is not None:
            values.update(factor=est.factor, sigma=est.sigma, edges=len(est.measured),
                          residual_rms_mm=1000 * float(np.sqrt(np.mean(est.residuals_m ** 2))),
                          rejected='; '.join(est.rejected))
        text = f'{est.factor:.6g} m/unit +/- {est.sigma:.2g}' if est else self._why_not
        self._diag.publish('ok' if est else 'warn', text, values, conversions.stamp_to_ns(stamp))

    def report(self) -> dict[str, Any]:
        est = self.estimate
        if est is None:
            return {'observable': False, 'reason': self._why_not}
        return {'observable': True, 'factor': est.factor, 'sigma': est.sigma,
                'interval': list(est.interval), 'edges': len(est.measured),
                'objects': est.objects_used, 'rejected': est.rejected,
                'residuals_m': est.residuals_m.tolist(), 'history': self.history}


def main(args: list[str] | None = None) -> None:
    common.run_node(ScaleNode, args)
