"""video_source publishes a video file's frames with the calibration's camera_info."""
from pathlib import Path

from absscale_ros import conversions
from absscale_ros.core import calibration
from absscale_ros.core.errors import AbsScaleError
from absscale_ros.core.types import CameraModel
from absscale_ros.nodes.common import SENSOR
from absscale_ros.nodes.video_source import VideoSourceNode
import cv2
import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from ros_helpers import spin_until
from sensor_msgs.msg import CameraInfo, Image


def _video(path: Path, frames: int = 6) -> list[np.ndarray]:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*'MJPG'), 30, (320, 240))
    images = []
    for i in range(frames):
        img = np.full((240, 320, 3), 40 * i % 255, np.uint8)
        cv2.putText(img, str(i), (100, 150), cv2.FONT_HERSHEY_SIMPLEX, 3, (255, 255, 255), 5)
        writer.write(img)
        images.append(img)
    writer.release()
    return images


def test_file_frames_and_calibration_published(context, tmp_path: Path) -> None:
    video = tmp_path / 'v.avi'
    sent = _video(video)
    # Calibrated at twice the resolution: the node must rescale the intrinsics.
    K = np.array([[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]])
    yaml_path = tmp_path / 'cam.yaml'
    yaml_path.write_text(calibration.model_to_yaml(CameraModel(640, 480, K)))
    listener = rclpy.create_node('listener', context=context)
    images, infos = [], []
    listener.create_subscription(Image, '/camera/image_raw', images.append, SENSOR)
    listener.create_subscription(CameraInfo, '/camera/camera_info', infos.append, SENSOR)
    node = VideoSourceNode(context=context, parameter_overrides=[
        Parameter('source', value=str(video)), Parameter('calibration_file', value=str(yaml_path)),
        Parameter('fps', value=30.0)])
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    executor.add_node(listener)
    assert spin_until(executor, lambda: node.finished)
    spin_until(executor, lambda: len(infos) >= node.published, timeout_s=1.0)
    # Best effort: the first frame may go out before discovery completes.
    assert node.published == len(sent) and len(images) >= len(sent) - 2
    model = conversions.camera_info_to_model(infos[-1])
    assert (model.width, model.height) == (320, 240)
    assert model.K[0, 0] == pytest.approx(250.0) and model.K[0, 2] == pytest.approx(159.5)
    got = conversions.image_msg_to_bgr(images[-1])
    assert np.abs(got.astype(int) - sent[len(images) - 1]).mean() < 8  # MJPG is lossy
    assert images[-1].header.stamp == infos[-1].header.stamp


def test_missing_file_is_a_clear_error(context, tmp_path: Path) -> None:
    with pytest.raises(AbsScaleError, match='no such video file'):
        VideoSourceNode(context=context, parameter_overrides=[
            Parameter('source', value=str(tmp_path / 'none.mp4'))])
