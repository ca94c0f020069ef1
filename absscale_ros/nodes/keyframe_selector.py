"""
keyframe_selector: only the frames worth reconstructing go on (``core/keyframes.py``).

Subscribes ``/absscale/frames`` (Image), ``/absscale/vertices`` (PointCloud2, one per frame,
paired with its frame by stamp in a bounded buffer) and ``/absscale/camera_info``. Publishes,
for each keyframe, the frame on ``/absscale/keyframes``, its vertices on
``/absscale/keyframe_vertices`` (an empty cloud when ``use_vertices`` is off: then frames
alone decide) and its tracked motion from the previous keyframe on
``/absscale/keyframe_motion`` (TransformStamped, scale-free; see
``conversions.tracked_step_to_msg``), all with the same stamp. Every parameter of
``KeyframeConfig`` is a ROS parameter. Each input message is acknowledged
(``common.StepAck``); ``/diagnostics`` once a second: frames, keyframes, blurred, degenerate,
tracking lost, time per frame.

With ``detect_on_request`` (offline) the detector looks only at the frames asked for on
``/absscale/detect_requests`` (std_msgs/Header, the frame's stamp): those that become keyframes
if the target is in them (``KeyframeSelector.needs_target``). Such a frame waits for its
vertices, and the frames after it wait behind it; every other frame is decided at once, the
same as with its vertices.
"""
from collections import Counter, deque
from dataclasses import fields
import time
from typing import Any

from absscale_ros import conversions
from absscale_ros.core import detect, errors, keyframe_geometry, keyframes, pairing
from absscale_ros.nodes import common, in_process
from geometry_msgs.msg import TransformStamped
import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from std_msgs.msg import Header

LIVE_DEPTH = 5  # live: frames (and vertex clouds) held at most, 0.17 s at 30 fps


class KeyframeSelectorNode(Node):

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('keyframe_selector', **kwargs)
        defaults = keyframes.KeyframeConfig()
        values = {f.name: self.declare_parameter(f.name, getattr(defaults, f.name)).value
                  for f in fields(keyframes.KeyframeConfig)}
        self._selector = keyframes.KeyframeSelector(keyframes.KeyframeConfig(**values))
        self._use_vertices = self.declare_parameter('use_vertices', True).value
        depth = self.declare_parameter('pair_depth', 10).value
        live = self.declare_parameter('qos', 'reliable').value == common.LIVE
        # Live, a selector that is behind drops the oldest frames (counted by `absscale run`)
        # instead of queueing up to 100 of them (3 s at 30 fps) in front of every keyframe.
        in_qos = common.live_input(LIVE_DEPTH) if live else common.RELIABLE
        self._pairer: pairing.StampPairer[Image, PointCloud2] = pairing.StampPairer(depth)
        self._on_request = self._use_vertices and not live and \
            self.declare_parameter('detect_on_request', False).value
        self._queue: deque[Image] = deque()  # on request: frames behind the one asked for
        self._asked: tuple[Image, keyframes.Measured] | None = None  # waiting for vertices
        self._camera: Any = None
        self._reasons: Counter[str] = Counter()
        self.keyframe_stamps_ns: list[int] = []
        self.unpaired = 0  # frames decided without their vertices
        self._times_ms: list[float] = []
        self._kf_pub = self.create_publisher(Image, '/absscale/keyframes', common.RELIABLE)
        self._kv_pub = self.create_publisher(PointCloud2, '/absscale/keyframe_vertices',
                                             common.RELIABLE)
        self._motion_pub = self.create_publisher(TransformStamped, '/absscale/keyframe_motion',
                                                 common.RELIABLE)
        self._diag = common.DiagnosticsPublisher(self, 'keyframes')
        self._ack = common.StepAck(self)
        self.create_subscription(CameraInfo, '/absscale/camera_info', self._on_info,
                                 common.RELIABLE)
        self._frames_sub = in_process.Subscription(self, Image, '/absscale/frames',
                                                   self._on_frame, in_qos)
        self._vert_sub = (self.create_subscription(PointCloud2, '/absscale/vertices',
                                                   self._on_vertices, in_qos)
                          if self._use_vertices else None)
        self._request_pub = self.create_publisher(Header, common.DETECT_REQUESTS_TOPIC,
                                                  common.RELIABLE) \
            if self._on_request else None
        self.create_timer(1.0, self._publish_diagnostics)

    def _on_info(self, msg: CameraInfo) -> None:
        try:
            self._camera = conversions.camera_info_to_model(msg)
        except errors.AbsScaleError as err:
            self.get_logger().warning(f'bad camera_info: {err}', throttle_duration_sec=5.0)

    def _on_frame(self, msg: Image) -> None:
        if self._on_request:
            self._queue.append(msg)
            self._work_queue()
        elif not self._use_vertices:
            self._decide(msg, None)
        else:
            self._settle(self._pairer.add_first(conversions.stamp_to_ns(msg.header.stamp), msg))

    def _on_vertices(self, msg: PointCloud2) -> None:
        if not self._on_request:
            self._settle(self._pairer.add_second(conversions.stamp_to_ns(msg.header.stamp), msg))
            return
        if self._asked is None or self._asked[0].header.stamp != msg.header.stamp:
            self._ack.ack(msg.header.stamp, self._vert_sub.topic_name)  # not asked for
            return
        frame, measured = self._asked
        self._asked = None
        self._finish(frame, measured, msg)
        self._work_queue()

    def _work_queue(self) -> None:
        """On request: decide the queued frames in order until one needs its vertices."""
        while self._asked is None and self._queue:
            frame = self._queue.popleft()
            measured = self._measure(frame)
            if measured is not None and self._selector.needs_target(measured):
                self._asked = (frame, measured)
                assert self._request_pub is not None
                self._request_pub.publish(frame.header)
            else:
                self._finish(frame, measured, None)

    def _settle(self, result: pairing.Pairing[Image, PointCloud2]) -> None:
        # A frame whose vertices never came (live: the detector skipped it) is still decided
        # on, so the selector keeps tracking, but it becomes a keyframe only when waiting for
        # a detected one would lose the track. It is older than the pairs just made: first.
        for _, frame in result.dropped_first:
            self.unpaired += 1
            self._decide(frame, None, detected=False)
        for _, frame, vertices in result.pairs:
            self._decide(frame, vertices)
        for _, vertices in result.dropped_second:
            self._ack.ack(vertices.header.stamp, self._vert_sub.topic_name)

    def _decide(self, frame: Image, vertices: PointCloud2 | None, detected: bool = True) -> None:
        self._finish(frame, self._measure(frame), vertices, detected)

    def _measure(self, frame: Image) -> keyframes.Measured | None:
        """The selector's measurement of the frame; None when it is dropped (counted)."""
        try:
            image = conversions.image_msg_to_bgr(frame)
            h, w = image.shape[:2]
            camera = self._camera if self._camera is not None and \
                (self._camera.width, self._camera.height) == (w, h) \
                else keyframe_geometry.nominal_camera(w, h)
            t0 = time.perf_counter()
            measured = self._selector.measure(conversions.stamp_to_ns(frame.header.stamp),
                                              image, camera)
            self._times_ms.append(1e3 * (time.perf_counter() - t0))
            return measured
        except errors.AbsScaleError as err:
            self._reasons['dropped'] += 1
            self.get_logger().warning(f'frame dropped: {err}', throttle_duration_sec=5.0)
            return None

    def _finish(self, frame: Image, measured: keyframes.Measured | None,
                vertices: PointCloud2 | None, detected: bool = True) -> None:
        """Decide on a measured frame, publish a keyframe, acknowledge the inputs."""
        outputs: list[str] = []
        try:
            if measured is not None:
                t0 = time.perf_counter()
                decision = self._selector.decide(measured, self._area(frame, vertices), detected)
                # The frame's time is its measure's and its decide's (a keyframe seeds corners
                # there): its measure's entry is the last one, as a frame asked for holds the
                # frames behind it back until it is decided.
                self._times_ms[-1] += 1e3 * (time.perf_counter() - t0)
                self._reasons[decision.reason] += 1
                if decision.keyframe:
                    outputs = self._publish_keyframe(frame, vertices, decision)
        except errors.AbsScaleError as err:
            self._reasons['dropped'] += 1
            self.get_logger().warning(f'frame dropped: {err}', throttle_duration_sec=5.0)
        self._ack.ack(frame.header.stamp, self._frames_sub.topic_name, outputs)
        if vertices is not None and self._vert_sub is not None:
            self._ack.ack(vertices.header.stamp, self._vert_sub.topic_name)

    @staticmethod
    def _area(frame: Image, vertices: PointCloud2 | None) -> float:
        """The largest target's area / the frame's, 0.0 without vertices."""
        if vertices is None or vertices.width == 0:
            return 0.0
        pts = conversions.cloud_msg_to_array(vertices)
        return keyframe_geometry.target_area_fraction(
            np.stack([pts['u'], pts['v']], axis=1), pts['object_id'], frame.width, frame.height)

    def _publish_keyframe(self, frame: Image, vertices: PointCloud2 | None,
                          decision: keyframes.Decision) -> list[str]:
        self._motion_pub.publish(conversions.tracked_step_to_msg(decision.step,
                                                                 decision.stamp_ns))
        self._kv_pub.publish(vertices if vertices is not None else
                             conversions.array_to_cloud_msg(
                                 np.zeros(0, detect.VERTEX_DTYPE), decision.stamp_ns,
                                 frame.header.frame_id))
        self._kf_pub.publish(frame)
        self.keyframe_stamps_ns.append(decision.stamp_ns)
        return [self._motion_pub.topic_name, self._kv_pub.topic_name, self._kf_pub.topic_name]

    def report(self) -> dict[str, Any]:
        """Counts and the keyframe stamps, for report.json."""
        times = np.array(self._times_ms or [np.nan])
        return {'frames': int(sum(self._reasons.values())),
                'keyframes': len(self.keyframe_stamps_ns),
                'unpaired': self.unpaired,
                'keyframe_stamps_ns': list(self.keyframe_stamps_ns),
                'decisions': dict(self._reasons),
                'tracking_lost': self._selector.lost_count,
                'time_ms_median': float(np.median(times))}

    def _publish_diagnostics(self) -> None:
        r = self.report()
        r.pop('keyframe_stamps_ns')
        level, text = 'ok', 'selecting keyframes'
        if self._camera is None:
            level, text = 'warn', 'no camera_info yet (assuming a 65 degree field of view)'
        elif r['frames'] and not r['keyframes']:
            level, text = 'warn', 'no keyframe yet (degenerate motion or blur)'
        self._diag.publish(level, text, r)


def main(args: list[str] | None = None) -> None:
    common.run_node(KeyframeSelectorNode, args)
