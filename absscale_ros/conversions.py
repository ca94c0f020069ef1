"""
The only module that turns ROS messages into numpy arrays and back.

Readers are duck-typed: they work on rclpy message instances (``data`` is an ``array.array``)
and on messages deserialized by rosbags (``data`` is a numpy array), since both expose the same
field names. Expected failures (malformed or unsupported messages) raise
:class:`absscale_ros.core.errors.MessageError` with the numbers involved.

Speed notes (1280x720 bgr8, see ``test/bench/bench_conversions.py``): readers return numpy
views on ``msg.data`` (``np.frombuffer``, no copy), so a returned array shares memory with the
message. Writers fill ``data`` with an ``array.array('B')`` built by ``frombytes`` from the
array's buffer: one copy, and the generated setter then stores it as is, even with
``ROS_PYTHON_CHECK_FIELDS=1`` (assigning ``bytes`` is as fast by default but checks every
byte when field checks are on; a list or an ndarray is about 100x slower).
"""
import array
from typing import Any

from builtin_interfaces.msg import Time
import cv2
import numpy as np
import numpy.typing as npt
from sensor_msgs.msg import CameraInfo, CompressedImage, Image

from absscale_ros.core import errors
from absscale_ros.core.types import CameraModel

_NS_PER_S = 1_000_000_000
_INT32_MIN, _INT32_MAX = -(2 ** 31), 2 ** 31 - 1


# --------------------------------------------------------------------------------------------
# Time
# --------------------------------------------------------------------------------------------

def stamp_to_ns(stamp: Any) -> int:
    """
    Return a ``builtin_interfaces/Time`` as integer nanoseconds.

    :param stamp: any object with integer ``sec`` and ``nanosec`` fields.
    :raises errors.MessageError: if ``nanosec`` is outside [0, 1e9).
    """
    sec, nanosec = int(stamp.sec), int(stamp.nanosec)
    if not 0 <= nanosec < _NS_PER_S:
        raise errors.MessageError(f'stamp nanosec {nanosec} outside [0, {_NS_PER_S})')
    return sec * _NS_PER_S + nanosec


def ns_to_stamp(ns: int) -> Time:
    """
    Return integer nanoseconds as a ``builtin_interfaces/Time``.

    Negative times keep ``nanosec`` in [0, 1e9) and put the sign in ``sec``, as rclpy does.

    :raises ValueError: if the time does not fit the message's int32 seconds.
    """
    sec, nanosec = divmod(int(ns), _NS_PER_S)
    if not _INT32_MIN <= sec <= _INT32_MAX:
        raise ValueError(f'{ns} ns does not fit builtin_interfaces/Time (int32 seconds)')
    return Time(sec=sec, nanosec=nanosec)


def _header(msg: Any, stamp_ns: int, frame_id: str) -> None:
    msg.header.stamp = ns_to_stamp(stamp_ns)
    msg.header.frame_id = frame_id


def _bytes_array(array_: np.ndarray) -> array.array:
    """Return the array's bytes as ``array.array('B')`` with a single copy (see module doc)."""
    flat = np.ascontiguousarray(array_).reshape(-1).view(np.uint8)
    out = array.array('B')
    out.frombytes(flat)
    return out


# --------------------------------------------------------------------------------------------
# Images
# --------------------------------------------------------------------------------------------

# encoding -> (numpy dtype of one channel, channels). Packed YUV 4:2:2 is two bytes a pixel.
_ENCODINGS: dict[str, tuple[np.dtype, int]] = {
    'bgr8': (np.dtype(np.uint8), 3), 'rgb8': (np.dtype(np.uint8), 3),
    'bgra8': (np.dtype(np.uint8), 4), 'rgba8': (np.dtype(np.uint8), 4),
    'bgr16': (np.dtype(np.uint16), 3), 'rgb16': (np.dtype(np.uint16), 3),
    'mono8': (np.dtype(np.uint8), 1), 'mono16': (np.dtype(np.uint16), 1),
    '8UC1': (np.dtype(np.uint8), 1), '8UC3': (np.dtype(np.uint8), 3),
    '16UC1': (np.dtype(np.uint16), 1), '32FC1': (np.dtype(np.float32), 1),
    'bayer_rggb8': (np.dtype(np.uint8), 1), 'bayer_bggr8': (np.dtype(np.uint8), 1),
    'bayer_gbrg8': (np.dtype(np.uint8), 1), 'bayer_grbg8': (np.dtype(np.uint8), 1),
    'uyvy': (np.dtype(np.uint8), 2), 'yuv422': (np.dtype(np.uint8), 2),
    'yuyv': (np.dtype(np.uint8), 2), 'yuv422_yuy2': (np.dtype(np.uint8), 2),
}
# 'yuv422' is UYVY byte order in sensor_msgs/image_encodings.hpp; 'yuv422_yuy2' is YUYV.
_YUV_TO_BGR = {'uyvy': cv2.COLOR_YUV2BGR_UYVY, 'yuv422': cv2.COLOR_YUV2BGR_UYVY,
               'yuyv': cv2.COLOR_YUV2BGR_YUYV, 'yuv422_yuy2': cv2.COLOR_YUV2BGR_YUYV}
_BGR_TO_YUV = {'uyvy': cv2.COLOR_BGR2YUV_UYVY, 'yuv422': cv2.COLOR_BGR2YUV_UYVY,
               'yuyv': cv2.COLOR_BGR2YUV_YUYV, 'yuv422_yuy2': cv2.COLOR_BGR2YUV_YUYV}
# OpenCV's new-style names (BayerRGGB) are the sensor's pattern, i.e. cv_bridge's BayerBG.
_BAYER_TO_BGR = {'bayer_rggb8': cv2.COLOR_BayerRGGB2BGR, 'bayer_bggr8': cv2.COLOR_BayerBGGR2BGR,
                 'bayer_gbrg8': cv2.COLOR_BayerGBRG2BGR, 'bayer_grbg8': cv2.COLOR_BayerGRBG2BGR}
IMAGE_ENCODINGS = tuple(_ENCODINGS)


def _encoding_info(encoding: str) -> tuple[np.dtype, int]:
    try:
        return _ENCODINGS[encoding]
    except KeyError:
        raise errors.MessageError(
            f'unsupported image encoding {encoding!r}; supported: {", ".join(_ENCODINGS)}'
        ) from None


def array_to_image_msg(image: npt.ArrayLike, encoding: str, stamp_ns: int = 0,
                       frame_id: str = '') -> Image:
    """
    Return ``image`` as a ``sensor_msgs/Image`` (little-endian, unpadded rows).

    :param image: HxW (mono, bayer raw, 16UC1, 32FC1) or HxWxC in the channel order of
        ``encoding``. For the YUV 4:2:2 encodings ('uyvy'/'yuv422', 'yuyv'/'yuv422_yuy2') either
        the packed HxWx2 uint8 bytes as they go on the wire, or an HxWx3 uint8 BGR image that is
        encoded with OpenCV (BT.601; W must be even).
    :param encoding: one of ``IMAGE_ENCODINGS``.
    :param stamp_ns: header stamp, ns.
    :raises errors.MessageError: on an unknown encoding.
    :raises ValueError: if the array's shape or dtype does not fit the encoding.
    """
    dtype, channels = _encoding_info(encoding)
    image = np.asarray(image)
    if channels == 2 and image.ndim == 3 and image.shape[2] == 3:
        if image.dtype != np.uint8 or image.shape[1] % 2:
            raise ValueError(f'BGR to {encoding} needs uint8 and an even width, got '
                             f'{image.dtype} {image.shape}')
        image = cv2.cvtColor(np.ascontiguousarray(image), _BGR_TO_YUV[encoding])
    expected = image.shape[:2] + ((channels,) if channels > 1 else ())
    if image.ndim not in (2, 3) or image.shape != expected or image.dtype != dtype:
        raise ValueError(f'{encoding} needs an array of {dtype} shaped HxW'
                         f'{"x%d" % channels if channels > 1 else ""}, got {image.dtype} '
                         f'{image.shape}')
    msg = Image()
    _header(msg, stamp_ns, frame_id)
    msg.height, msg.width = int(image.shape[0]), int(image.shape[1])
    msg.encoding = encoding
    # Multi-byte pixels go on the wire in little-endian order (is_bigendian = 0).
    msg.is_bigendian = 0
    msg.step = msg.width * channels * dtype.itemsize
    msg.data = _bytes_array(image.astype(dtype.newbyteorder('<'), copy=False))
    return msg


# --------------------------------------------------------------------------------------------
# Compressed images
# --------------------------------------------------------------------------------------------

def bgr_to_compressed_msg(image: npt.ArrayLike, fmt: str = 'jpeg', quality: int = 90,
                          stamp_ns: int = 0, frame_id: str = '', *,
                          png_level: int = 3) -> CompressedImage:
    """
    Return an image compressed as compressed_image_transport would publish it.

    The format string is ``'<encoding>; <fmt> compressed <encoding>'``, e.g.
    ``'bgr8; jpeg compressed bgr8'``.

    :param image: HxWx3 uint8 BGR, or HxW uint8 (mono8) or, for PNG only, HxW uint16 (mono16).
    :param fmt: 'jpeg' (or 'jpg') or 'png'.
    :param quality: JPEG quality in [1, 100]; unused for PNG.
    :param png_level: PNG zlib level in [0, 9]; 3 keeps a 720p frame well under 50 ms.
    :raises ValueError: on an unknown format, a bad quality or an unsupported array.
    """
    image = np.asarray(image)
    fmt = 'jpeg' if fmt.lower() == 'jpg' else fmt.lower()
    if fmt not in ('jpeg', 'png'):
        raise ValueError(f"compressed format must be 'jpeg' or 'png', got {fmt!r}")
    if image.ndim == 3 and image.shape[2] == 3 and image.dtype == np.uint8:
        encoding = 'bgr8'
    elif image.ndim == 2 and image.dtype == np.uint8:
        encoding = 'mono8'
    elif image.ndim == 2 and image.dtype == np.uint16 and fmt == 'png':
        encoding = 'mono16'
    else:
        raise ValueError(f'cannot compress a {image.dtype} array shaped {image.shape} as {fmt}')
    if fmt == 'jpeg':
        if not 1 <= quality <= 100:
            raise ValueError(f'JPEG quality must be in [1, 100], got {quality}')
        params = [cv2.IMWRITE_JPEG_QUALITY, int(quality)]
    else:
        if not 0 <= png_level <= 9:
            raise ValueError(f'PNG level must be in [0, 9], got {png_level}')
        params = [cv2.IMWRITE_PNG_COMPRESSION, int(png_level)]
    ok, buffer = cv2.imencode('.jpg' if fmt == 'jpeg' else '.png', image, params)
    if not ok:
        raise ValueError(f'OpenCV could not encode a {image.shape} image as {fmt}')
    msg = CompressedImage()
    _header(msg, stamp_ns, frame_id)
    msg.format = f'{encoding}; {fmt} compressed {encoding}'
    msg.data = _bytes_array(buffer)
    return msg


# --------------------------------------------------------------------------------------------
# Camera info
# --------------------------------------------------------------------------------------------

# Number of D coefficients ROS writes for each model ('none' goes out as zero plumb_bob).
_DIST_SIZES = {'plumb_bob': 5, 'rational_polynomial': 8, 'equidistant': 4}


def camera_model_to_info_msg(model: CameraModel, stamp_ns: int = 0,
                             frame_id: str = '') -> CameraInfo:
    """
    Return a ``sensor_msgs/CameraInfo`` for a monocular camera.

    R is the identity and P = [K | 0] (no stereo baseline, no rectification). A model without
    distortion goes out as 'plumb_bob' with five zero coefficients, which every ROS consumer
    understands.
    """
    msg = CameraInfo()
    _header(msg, stamp_ns, frame_id)
    msg.width, msg.height = int(model.width), int(model.height)
    if model.distortion_model == 'none':
        msg.distortion_model = 'plumb_bob'
        msg.d = [0.0] * _DIST_SIZES['plumb_bob']
    else:
        msg.distortion_model = model.distortion_model
        msg.d = [float(c) for c in model.dist]
    msg.k = np.asarray(model.K, dtype=np.float64).reshape(9)
    msg.r = np.eye(3).reshape(9)
    msg.p = np.hstack([model.K, np.zeros((3, 1))]).astype(np.float64).reshape(12)
    return msg
