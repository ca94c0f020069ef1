"""
video_source: a V4L2 device, video file or stream URL published as a ROS camera.

Publishes ``/camera/image_raw`` (Image bgr8) and ``/camera/camera_info`` (from a ROS calibration
YAML, see ``absscale calibrate``) with the same stamp, sensor-data QoS, and ``/diagnostics``.
"""
from pathlib import Path
import time
from typing import Any

from absscale_ros import conversions
from absscale_ros.core import calibration
from absscale_ros.core.errors import AbsScaleError
from absscale_ros.core.types import CameraModel
from absscale_ros.nodes import common
import cv2
import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image


class VideoSourceNode(Node):

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('video_source', **kwargs)
        p = {x.name: x.value for x in self.declare_parameters('', [
            ('source', '0'), ('calibration_file', ''), ('frame_id', 'camera'),
            ('fps', 0.0), ('loop', False)])}
        self._source, self._frame_id, self._loop = p['source'], p['frame_id'], p['loop']
        self._cap = self._open()
        fps = p['fps'] or self._cap.get(cv2.CAP_PROP_FPS) or 30.0
        self._model = self._load_model(p['calibration_file'])
        self._image_pub = self.create_publisher(Image, '/camera/image_raw', common.SENSOR)
        self._info_pub = self.create_publisher(CameraInfo, '/camera/camera_info', common.SENSOR)
        self._diag = common.DiagnosticsPublisher(self, 'camera')
        self.published = self.failures = 0
        self.finished = False
        self.create_timer(1.0 / fps, self._grab)
        self.create_timer(1.0, self._diagnose)
        self.get_logger().info(f'publishing {self._source} at {fps:.1f} fps')

    def _open(self) -> Any:
        source: Any = int(self._source) if self._source.isdigit() else self._source
        if isinstance(source, str) and '://' not in source and not Path(source).exists():
            raise AbsScaleError(f'{source}: no such video file')
        cap = cv2.VideoCapture(source)
        if not cap.isOpened():
            raise AbsScaleError(f'{self._source}: cannot open as a video source')
        return cap

    def _load_model(self, path: str) -> CameraModel | None:
        if not path:
            self.get_logger().warning('no calibration_file: publishing camera_info with a '
                                      'guessed focal length; metric results need a calibration')
            return None
        return calibration.load_calibration_yaml(path)

    def _guess_model(self, width: int, height: int) -> CameraModel:
        f = 0.8 * width  # about 64 degrees horizontal field of view
        return CameraModel(width, height, np.array([[f, 0, (width - 1) / 2],
                                                    [0, f, (height - 1) / 2], [0, 0, 1]]))

    def _grab(self) -> None:
        if self.finished:
            return
        ok, frame = self._cap.read()
        if not ok and self._loop and not self._source.isdigit():
            self._cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
            ok, frame = self._cap.read()
        if not ok:
            self.failures += 1
            if not self._source.isdigit():
                self.finished = True
                self.get_logger().info(f'{self._source}: end of video after '
                                       f'{self.published} frames')
            return
        h, w = frame.shape[:2]
        model = self._model or self._guess_model(w, h)
        if (model.width, model.height) != (w, h):
            model = model.resized(w, h)  # calibrated at another resolution, same optics
        stamp = time.time_ns()
        self._image_pub.publish(conversions.array_to_image_msg(frame, 'bgr8', stamp,
                                                               self._frame_id))
        self._info_pub.publish(conversions.camera_model_to_info_msg(model, stamp, self._frame_id))
        self.published += 1

    def _diagnose(self) -> None:
        level = 'ok' if self.failures == 0 or self.finished else 'warn'
        values = {'source': self._source, 'frames': self.published,
                  'read_failures': self.failures, 'calibrated': self._model is not None}
        self._diag.publish(level, 'end of video' if self.finished else 'streaming', values)

    def destroy_node(self) -> None:
        self._cap.release()
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    common.run_node(VideoSourceNode, args)
