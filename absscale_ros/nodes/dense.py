"""
dense: the metric dense cloud, from keyframe stereo fused with the metric keyframe poses.

Subscribes ``/absscale/keyframes`` (Image), ``/absscale/camera_info`` and
``/absscale/scaled_path`` (metric T_world_cam of every keyframe, from ``scale``). Keyframes
wait (at the working scale) until a metric pose exists for them; each path update runs
``core/dense_fusion.py`` (new keyframes get depth maps, from pairs and a plane sweep; moved
ones are recomputed) and, when the cloud changed, publishes it on ``/scaled_cloud`` (x y z in
metres, rgb, normals; reliable + TRANSIENT_LOCAL depth 1). ``absscale run`` starts it only
with ``enabled: true``, and then the scale node's sparse cloud moves to
``/absscale/sparse_cloud_metric``.
"""
import time
from typing import Any

from absscale_ros import conversions
from absscale_ros.core import dense_facade, dense_fill, dense_fusion, dense_ground, dense_stereo, \
    dense_sweep
from absscale_ros.nodes import common
from nav_msgs.msg import Path
import numpy as np
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image, PointCloud2

# The scaled path is latched; ask for TRANSIENT_LOCAL, deep enough that none is lost between
# two acknowledgements.
LATE_JOINER = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)


class DenseNode(Node):

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('dense', **kwargs)
        stereo = common.declare_config(self, dense_stereo.StereoConfig(), 'stereo')
        fusion = common.declare_config(self, dense_fusion.FusionConfig(), 'fusion')
        sweep = common.declare_config(self, dense_sweep.SweepConfig(), 'sweep')
        facade = common.declare_config(self, dense_facade.FacadeConfig(), 'facade')
        fill = common.declare_config(self, dense_fill.FillConfig(), 'fill')
        ground = common.declare_config(self, dense_ground.GroundConfig(), 'ground')
        self.declare_parameter('enabled', True)  # read by `absscale run`: start this node?
        self._frame = self.declare_parameter('frame_id', 'map').value
        self._fusion = dense_fusion.DenseFusion(stereo, fusion, sweep, facade, fill, ground)
        self._camera: Any = None
        self._points = 0
        self._stamp_ns = 0  # of the latest path: the cloud's stamp
        self.update_s: list[float] = []  # CPU time of each update that changed the cloud
        self.update_wall_s: list[float] = []
        self._pub = self.create_publisher(PointCloud2, '/scaled_cloud', common.LATCHED)
        self._ack = common.StepAck(self)
        self._diag = common.DiagnosticsPublisher(self, 'dense cloud')
        self.create_subscription(CameraInfo, '/absscale/camera_info', self._on_info,
                                 common.RELIABLE)
        self._kf_sub = self.create_subscription(Image, '/absscale/keyframes', self._on_keyframe,
                                                common.RELIABLE)
        self._path_sub = self.create_subscription(Path, '/absscale/scaled_path', self._on_path,
                                                  LATE_JOINER)
        # Depth maps past the per-update budget are computed with each keyframe image and, once
        # the graph is idle for a second, by a timer (a busy timer would starve the other
        # nodes of this executor and time the lossless replay out).
        self._last_msg = time.monotonic()
        self.create_timer(1.0, self._catch_up_when_idle)

    def _on_info(self, msg: CameraInfo) -> None:
        self._camera = conversions.camera_info_to_model(msg)

    def _on_keyframe(self, msg: Image) -> None:
        image = conversions.image_msg_to_bgr(msg)
        cam = self._camera
        if cam is None or (cam.width, cam.height) != (image.shape[1], image.shape[0]):
            self.get_logger().warning('keyframe without a camera_info of its size: skipped',
                                      throttle_duration_sec=5.0)
        else:
            self._fusion.add_keyframe(conversions.stamp_to_ns(msg.header.stamp), image, cam)
        self._ack.ack(msg.header.stamp, self._kf_sub.topic_name)
        self._catch_up()
        self._last_msg = time.monotonic()

    def _on_path(self, msg: Path) -> None:
        c0, t0 = time.process_time(), time.perf_counter()
        poses, stamps = conversions.path_msg_to_poses(msg)
        self._stamp_ns = conversions.stamp_to_ns(msg.header.stamp)
        changed = self._fusion.update(dense_fusion.pose_matrices(poses, stamps))
        outputs = self._publish(c0, t0) if changed else []
        self._ack.ack(msg.header.stamp, self._path_sub.topic_name, outputs)
        self._last_msg = time.monotonic()

    def _catch_up_when_idle(self) -> None:
        if time.monotonic() - self._last_msg > 1.0:
            self._catch_up()

    def _catch_up(self) -> None:
        c0, t0 = time.process_time(), time.perf_counter()
        if self._fusion.catch_up():
            self._publish(c0, t0)

    def _publish(self, c0: float, t0: float) -> list[str]:
        xyz, rgb, normals = self._fusion.cloud()
        self._pub.publish(conversions.dense_cloud_msg(xyz, rgb, normals, self._stamp_ns,
                                                      self._frame))
        self._points = len(xyz)
        self.update_s.append(time.process_time() - c0)
        self.update_wall_s.append(time.perf_counter() - t0)
        self._diag.publish('ok', f'{self._points} points', self.report_summary(), self._stamp_ns)
        return [self._pub.topic_name]

    def report_summary(self) -> dict[str, Any]:
        times = self.update_s or [float('nan')]
        return {'points': self._points, 'keyframes_fused': self._fusion.keyframes,
                'depth_maps_computed': self._fusion.depth_computed,
                'sweeps_computed': self._fusion.sweeps_computed, 'updates': len(self.update_s),
                'update_cpu_s_median': float(np.median(times)),
                'update_cpu_s_p95': float(np.percentile(times, 95))}

    def report(self) -> dict[str, Any]:
        """For report.json: the summary and every update's CPU and wall time."""
        return {**self.report_summary(), 'update_s': self.update_s,
                'update_wall_s': self.update_wall_s}


def main(args: list[str] | None = None) -> None:
    common.run_node(DenseNode, args)
