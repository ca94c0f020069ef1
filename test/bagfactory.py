"""Tiny real bags for tests: JPEG frames and camera_info at 30 fps, written with bagio."""
from pathlib import Path

from absscale_ros import bagio, conversions
from absscale_ros.core.types import CameraModel
import numpy as np
from rclpy.serialization import serialize_message

IMAGE_TOPIC = '/camera/image_raw/compressed'
INFO_TOPIC = '/camera/camera_info'
PERIOD_NS = 33_333_333


def write_camera_bag(path: Path, frames: int = 20, size: tuple[int, int] = (320, 240),
                     period_ns: int = PERIOD_NS) -> list[bytes]:
    """Write frames with a camera_info before each; return the image messages' CDR bytes."""
    rng = np.random.default_rng(1)
    w, h = size
    model = CameraModel(w, h, np.array([[0.8 * w, 0, w / 2], [0, 0.8 * w, h / 2], [0, 0, 1]]))
    images = []
    with bagio.BagWriter(path) as writer:
        for i in range(frames):
            stamp = 1_700_000_000_000_000_000 + i * period_ns
            info = conversions.camera_model_to_info_msg(model, stamp, 'camera')
            writer.write(INFO_TOPIC, 'sensor_msgs/msg/CameraInfo', stamp,
                         serialize_message(info))
            img = (rng.random((h, w, 3)) * 255).astype(np.uint8)
            data = serialize_message(conversions.bgr_to_compressed_msg(img, 'jpeg', 80, stamp,
                                                                       'camera'))
            writer.write(IMAGE_TOPIC, 'sensor_msgs/msg/CompressedImage', stamp + 1, data)
            images.append(data)
    return images
