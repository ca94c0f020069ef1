"""
frame_ingest: camera frames in any supported encoding become clean bgr8 frames.

Subscribes ``image_topic`` (sensor_msgs/Image, or CompressedImage when ``compressed``) and
``camera_info_topic``; publishes ``/absscale/camera_info`` then ``/absscale/frames`` (bgr8,
optionally downscaled to ``max_width_px`` and undistorted, intrinsics to match) with the
source stamp. A frame waits up to ``info_wait_s`` for a camera_info of its size (in step mode
the info travels on another topic and may arrive just after it); a resolution change
re-initialises; frames that never get one are dropped with a diagnostic. Every input frame is
acknowledged (``common.StepAck``). ``calibration_file`` (a ROS calibration YAML) replaces
camera_info. ``/diagnostics`` once a second: decoded, dropped, missing (stamp gaps in live
mode), waiting for camera_info.

Offline (``decode_thread``, reliable input) frames are decoded and published in arrival order
on a worker thread: OpenCV lets go of the GIL while it decodes, so the JPEG decoding (~4 ms a
1280x720 frame) overlaps the work of the nodes beside it (the detector on the frame before).
"""
from concurrent.futures import ThreadPoolExecutor
import threading
import time
from typing import Any

from absscale_ros import conversions
from absscale_ros.core import calibration, errors, ingest, pairing
from absscale_ros.nodes import common, in_process
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, CompressedImage, Image


class FrameIngestNode(Node):

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('frame_ingest', **kwargs)
        p = {x.name: x.value for x in self.declare_parameters('', [
            ('image_topic', '/camera/image_raw/compressed'), ('compressed', True),
            ('camera_info_topic', '/camera/camera_info'), ('qos', 'reliable'),
            ('max_width_px', 0), ('undistort', False), ('undistort_alpha', 0.0),
            ('calibration_file', ''), ('info_wait_s', 1.0), ('hold_frames', 5),
            ('decode_thread', True)])}
        self._prep = ingest.FramePreparer(ingest.IngestConfig(
            p['max_width_px'], p['undistort'], p['undistort_alpha']))
        self._calib = (calibration.load_calibration_yaml(p['calibration_file'])
                       if p['calibration_file'] else None)
        self._held: pairing.HoldQueue[tuple[Any, Any]] = pairing.HoldQueue(
            p['hold_frames'], p['info_wait_s'])
        self._info: Any = None  # latest input CameraModel
        self._gaps = ingest.GapCounter()
        self.decoded = self.dropped = self.reinit = 0
        self._last_problem = ''
        qos = common.SENSOR if p['qos'] == 'sensor_data' else common.RELIABLE
        # The detector and the selector beside it take a frame as it is (``in_process``).
        self._frames_pub = in_process.Publisher(self, Image, '/absscale/frames', common.RELIABLE)
        self._info_pub = self.create_publisher(CameraInfo, '/absscale/camera_info',
                                               common.RELIABLE)
        self._diag = common.DiagnosticsPublisher(self, 'ingest')
        self._ack = common.StepAck(self)
        self._decode = (conversions.compressed_msg_to_bgr if p['compressed']
                        else conversions.image_msg_to_bgr)
        # Live, a worker's queue would hold frames a node that is behind must drop: inline.
        self._worker = ThreadPoolExecutor(1, 'frame_decode') \
            if p['decode_thread'] and p['qos'] != common.LIVE else None
        self._lock = threading.Lock()  # the worker's publishing against the callbacks'
        self._sub = self.create_subscription(CompressedImage if p['compressed'] else Image,
                                             p['image_topic'], self._on_frame, qos)
        if self._calib is None:
            self.create_subscription(CameraInfo, p['camera_info_topic'], self._on_info, qos)
        self.create_timer(0.05, self._expire)
        self.create_timer(1.0, self._publish_diagnostics)

    def _on_info(self, msg: CameraInfo) -> None:
        if self._worker is None:
            self._take_info(msg)
        else:  # behind the frames that came before it, as inline: not applied to them
            self._worker.submit(self._take_info, msg).add_done_callback(self._raise_in_log)

    def _take_info(self, msg: CameraInfo) -> None:
        try:
            info = conversions.camera_info_to_model(msg)
        except errors.AbsScaleError as err:
            self._problem(f'bad camera_info: {err}')
            return
        with self._lock:
            self._info = info
            for header, image in self._held.release(self._ready):
                self._emit(header, image)

    def _camera_for(self, image: Any) -> Any:
        """The input camera model of a frame of this size, or None."""
        h, w = image.shape[:2]
        cam = self._info if self._calib is None else self._calib
        if cam is not None and (cam.width, cam.height) != (w, h) and self._calib is not None \
                and abs(cam.width * h - cam.height * w) <= 0.01 * w * h:
            cam = cam.resized(w, h)  # a calibration made at another resolution, same aspect
        return cam if cam is not None and (cam.width, cam.height) == (w, h) else None

    def _ready(self, item: tuple[Any, Any]) -> bool:
        return self._camera_for(item[1]) is not None

    def _on_frame(self, msg: Any) -> None:
        if self._worker is None:
            self._handle(msg)
        else:  # one worker: frames go out in the order they came
            self._worker.submit(self._handle_on_worker, msg)

    def _handle_on_worker(self, msg: Any) -> None:
        """``_handle`` on the decode worker. A bug there (not a bad frame, which ``_handle``
        drops itself) would otherwise leave the frame unacknowledged and the run stalled for
        its step timeout: it is logged as an error and the frame counted as dropped."""
        try:
            self._handle(msg)
        except Exception as err:  # noqa: BLE001 (the worker's last resort, logged loudly)
            self.get_logger().error(f'frame_ingest worker: {err!r}')
            with self._lock:
                self._drop(msg.header, f'internal error: {err!r}')

    def _handle(self, msg: Any) -> None:
        try:
            image: Any = self._decode(msg)
        except errors.AbsScaleError as err:
            image = err
        with self._lock:
            self._gaps.add(conversions.stamp_to_ns(msg.header.stamp))
            if isinstance(image, errors.AbsScaleError):
                self._drop(msg.header, f'undecodable frame: {image}')
            elif self._ready((msg.header, image)):
                self._emit(msg.header, image)
            else:
                for header, old in self._held.add((msg.header, image), time.monotonic()):
                    self._drop(header, f'no camera_info for a {old.shape[1]}x{old.shape[0]} '
                                       'frame')

    def _raise_in_log(self, done: Any) -> None:
        if done.exception() is not None:  # a bug, not a bad frame: loud, as inline it would be
            self.get_logger().error(f'frame_ingest worker: {done.exception()!r}')

    def _emit(self, header: Any, image: Any) -> None:
        if self._prep.configure(self._camera_for(image)):
            self.reinit += 1
            out = self._prep.camera_out
            self.get_logger().info(f'input {image.shape[1]}x{image.shape[0]}: publishing '
                                   f'{out.width}x{out.height}')
        try:
            frame = self._prep.process(image)
        except errors.AbsScaleError as err:
            self._drop(header, str(err))
            return
        stamp_ns = conversions.stamp_to_ns(header.stamp)
        self._info_pub.publish(conversions.camera_model_to_info_msg(
            self._prep.camera_out, stamp_ns, header.frame_id))
        self._frames_pub.publish(conversions.array_to_image_msg(
            frame, 'bgr8', stamp_ns, header.frame_id))
        self.decoded += 1
        # camera_info is not listed: its consumers do not acknowledge it (not frame-carrying).
        self._ack.ack(header.stamp, self._sub.topic_name, [self._frames_pub.topic_name])

    def _drop(self, header: Any, why: str) -> None:
        self.dropped += 1
        self._problem(f'frame dropped: {why}')
        self._ack.ack(header.stamp, self._sub.topic_name)

    def _problem(self, text: str) -> None:
        self._last_problem = text
        self.get_logger().warning(text, throttle_duration_sec=5.0)

    def _expire(self) -> None:
        with self._lock:
            for header, image in self._held.expire(time.monotonic()):
                self._drop(header, f'no camera_info matching {image.shape[1]}x{image.shape[0]} '
                                   f'within {self._held.wait_s} s')

    def report(self) -> dict[str, Any]:
        """Counts for report.json."""
        return {'frames_decoded': self.decoded, 'frames_dropped': self.dropped,
                'frames_missing': self._gaps.missing, 'reinitialised': self.reinit,
                'waiting': len(self._held)}

    def _publish_diagnostics(self) -> None:
        level, text = 'ok', 'publishing frames'
        if self._info is None and self._calib is None:
            level, text = 'warn', 'waiting for camera_info'
        elif self._last_problem:
            level, text = 'warn', self._last_problem
        self._last_problem = ''
        self._diag.publish(level, text, self.report())

    def destroy_node(self) -> None:
        if self._worker is not None:
            self._worker.shutdown(cancel_futures=True)
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    common.run_node(FrameIngestNode, args)
