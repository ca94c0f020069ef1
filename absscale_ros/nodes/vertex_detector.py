"""
vertex_detector: calibration-object vertices in every frame (the paper's Step 1).

Subscribes ``/absscale/frames`` (sensor_msgs/Image bgr8) and ``/absscale/camera_info``.
Publishes, for every frame, ``/absscale/vertices`` (sensor_msgs/PointCloud2, stamped and framed
like the source frame, height 1, one point per vertex, an empty cloud when nothing is found so
consumers can tell "looked and saw nothing" from "no data"). Fields, little-endian:

=============== ======= ===============================================================
``u``, ``v``    float32 vertex position in the frame, px (pixel centres at integers)
``vertex_id``   int32   sheet: 0..3 clockwise from the corner nearest the top-left;
                        cube: colour mask (1 red, 2 yellow, 4 purple) + 8 * ordinal
``object_id``   int32   index of the target in this frame
``target_type`` int32   0 sheet, 1 cube
``edge_mask``   int32   bit j: an image edge joins this vertex and the j-th vertex of the
                        same object (in cloud order)
``score``       float32 edge support of the object, 0-1
=============== ======= ===============================================================

With ``qos: sensor_data`` (a live camera) it looks at most ``live_max_rate_hz`` frames a second
(by frame stamp) and publishes nothing for the frames in between, so that the SfM, which needs
the CPU more, is not starved; the keyframe selector places keyframes on frames it looked at.

With ``detect_on_request`` (offline) it looks only at the frames the keyframe selector asks for
on ``/absscale/detect_requests`` (std_msgs/Header, the frame's stamp): those that become
keyframes if the target is in them (136 of the 60 s bag's 1800 frames); the selector decides
every other frame the same without their vertices (``KeyframeSelector.needs_target``). The
cube is then tracked from one looked-at frame to the next.

``/absscale/debug_image`` (Image bgr8, the overlay) is drawn only while someone subscribes.
``/diagnostics`` carries frames, detection rate and time per frame once a second. In step mode
each frame is acknowledged on ``/absscale/ack`` (``common.StepAck``).
"""
import time
from typing import Any

from absscale_ros import conversions
from absscale_ros.core import (cube_track, detect, detect_cube, detect_sheet, errors,
                               pairing, sheet_track)
from absscale_ros.nodes import common, in_process
import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from std_msgs.msg import Header


class VertexDetectorNode(Node):

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('vertex_detector', **kwargs)
        target = self.declare_parameter('target', 'auto').value
        auto_sheets = self.declare_parameter('auto_sheets', ['letter', 'a4']).value
        qos = self.declare_parameter('qos', 'reliable').value  # reliable | sensor_data
        rate = float(self.declare_parameter('live_max_rate_hz', 10.0).value)
        # Offline (reliable) every frame is detected: the replay is lossless.
        self._min_gap_ns = int(1e9 / rate) if qos == 'sensor_data' and rate > 0.0 else 0
        self._last_stamp_ns: int | None = None
        self._cfg = detect.DetectConfig(
            target=target, auto_sheets=tuple(auto_sheets),
            sheet=common.declare_config(self, detect_sheet.SheetConfig(), 'sheet'),
            cube=common.declare_config(self, detect_cube.CubeConfig(), 'cube'))
        # Frames come in order: the cube is looked for first where the last frame showed it.
        self._tracker = cube_track.CubeTracker(self._cfg.cube)
        self._sheets = sheet_track.SheetHistory()  # and a sheet's aspect over the last frames
        in_qos = common.SENSOR if qos == 'sensor_data' else common.RELIABLE
        # Offline only: live, the rate cap above leaves the SfM its CPU instead.
        on_request = self.declare_parameter('detect_on_request', False).value \
            and qos != 'sensor_data'
        depth = self.declare_parameter('pair_depth', 10).value
        # Frames held until the selector asked for them or decided them without (a newer one
        # asked for: it decides in order), and requests that overtook their frame.
        self._requested: pairing.StampPairer[Image, Header] | None = \
            pairing.StampPairer(depth) if on_request else None
        self._vertices_pub = self.create_publisher(PointCloud2, '/absscale/vertices',
                                                   common.RELIABLE)
        self._debug_pub = self.create_publisher(Image, '/absscale/debug_image', 1)
        self._diag = common.DiagnosticsPublisher(self, 'detection')
        self._ack = common.StepAck(self)
        self._K: np.ndarray | None = None
        self._dist: np.ndarray | None = None  # OpenCV-order coefficients (not fisheye)
        self._info_sub = self.create_subscription(CameraInfo, '/absscale/camera_info',
                                                  self._on_info, in_qos)
        self._frames_sub = in_process.Subscription(self, Image, '/absscale/frames',
                                                   self._on_frame, in_qos)
        if self._requested is not None:
            self.create_subscription(Header, common.DETECT_REQUESTS_TOPIC, self._on_request,
                                     common.RELIABLE)
        self._frames = self._with_target = self._dropped = self._skipped = self._offered = 0
        self._times_ms: list[float] = []
        self._timer = self.create_timer(1.0, self._publish_diagnostics)

    def _on_info(self, msg: CameraInfo) -> None:
        try:
            model = conversions.camera_info_to_model(msg)
            # The sheet's aspect check undoes the lens: at the image border a barrel lens
            # moved a 4:3 board to 1.6 % off letter. A fisheye model is not in OpenCV's order.
            self._K, self._dist = model.K, (None if model.distortion_model == 'equidistant'
                                            else model.dist)
        except errors.AbsScaleError as err:
            self.get_logger().warning(f'bad camera_info: {err}', throttle_duration_sec=5.0)

    def _on_frame(self, msg: Image) -> None:
        stamp_ns = conversions.stamp_to_ns(msg.header.stamp)
        if self._requested is not None:
            # Acknowledged at once: a frame asked for stays in flight at the selector, which
            # waits for its vertices.
            self._ack.ack(msg.header.stamp, self._frames_sub.topic_name)
            self._offered += 1
            self._detect_paired(self._requested.add_first(stamp_ns, msg))
            return
        if self._skip(stamp_ns):
            self._skipped += 1
            return
        self._ack.ack(msg.header.stamp, self._frames_sub.topic_name, self._detect(msg))

    def _on_request(self, msg: Header) -> None:
        assert self._requested is not None
        self._detect_paired(self._requested.add_second(conversions.stamp_to_ns(msg.stamp), msg))

    def _detect_paired(self, paired: pairing.Pairing[Image, Header]) -> None:
        for stamp_ns, _ in paired.dropped_second:
            self.get_logger().error(f'asked for frame {stamp_ns}, which is not held (more '
                                    'frames in flight than pair_depth?)')
        for stamp_ns, frame, _ in paired.pairs:
            if not self._detect(frame):  # the selector waits for an answer: nothing found
                self._vertices_pub.publish(conversions.array_to_cloud_msg(
                    np.zeros(0, detect.VERTEX_DTYPE), stamp_ns, frame.header.frame_id))

    def _detect(self, msg: Image) -> list[str]:
        """Detect the frame's targets, publish its vertices; return the topics published."""
        stamp_ns = conversions.stamp_to_ns(msg.header.stamp)
        outputs: list[str] = []
        try:
            image = conversions.image_msg_to_bgr(msg)
            t0 = time.perf_counter()
            result = detect.detect(image, self._cfg, self._K, self._dist, self._tracker,
                                   self._sheets)
            self._times_ms.append(1e3 * (time.perf_counter() - t0))
            cloud = detect.vertices_array(result)
            self._vertices_pub.publish(
                conversions.array_to_cloud_msg(cloud, stamp_ns, msg.header.frame_id))
            outputs.append(self._vertices_pub.topic_name)
            self._frames += 1
            self._with_target += bool(result.detections)
            if self._debug_pub.get_subscription_count() > 0:
                self._debug_pub.publish(conversions.array_to_image_msg(
                    detect.draw_overlay(image, result), 'bgr8', stamp_ns, msg.header.frame_id))
                outputs.append(self._debug_pub.topic_name)
        except errors.AbsScaleError as err:
            self._dropped += 1
            self.get_logger().warning(f'frame dropped: {err}', throttle_duration_sec=5.0)
        return outputs

    def _skip(self, stamp_ns: int) -> bool:
        """Live: whether this frame comes too soon after the last one looked at."""
        # 2 ms of slack: a 30 fps stamp grid must not turn 10 Hz into 7.5 Hz.
        if self._last_stamp_ns is not None and 0 <= stamp_ns - self._last_stamp_ns < \
                self._min_gap_ns - 2_000_000:
            return True
        self._last_stamp_ns = stamp_ns
        return False

    def report(self) -> dict[str, Any]:
        """Counts for report.json."""
        times = np.array(self._times_ms) if self._times_ms else np.array([np.nan])
        return {'frames': self._frames, 'frames_with_target': self._with_target,
                'frames_dropped': self._dropped, 'frames_skipped_by_rate': self._skipped,
                # detect_on_request: the frames the selector decided without their vertices
                'frames_not_requested': max(0, self._offered - self._frames - self._dropped),
                'detection_rate': self._with_target / self._frames if self._frames else None,
                'cube_frames_in_box': self._tracker.box_frames,  # settled near the last cube
                'cube_frames_held': self._tracker.held_frames,  # one face of the last cube
                'time_ms_median': float(np.median(times)),
                'time_ms_p95': float(np.percentile(times, 95))}

    def _publish_diagnostics(self) -> None:
        r = self.report()
        level, text = 'ok', 'detecting'
        if self._K is None:
            level, text = 'warn', 'waiting for camera_info (aspect check estimates focal)'
        elif self._frames and not self._with_target:
            level, text = 'warn', 'target not seen'
        self._diag.publish(level, text, r)


def main(args: list[str] | None = None) -> None:
    common.run_node(VertexDetectorNode, args)
