"""sensor_msgs/Image to numpy and back, for every encoding we read."""
from typing import Any

from absscale_ros.conversions.stamps import bytes_array, set_header
from absscale_ros.core import errors
import cv2
import numpy as np
import numpy.typing as npt
from sensor_msgs.msg import Image


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


def array_to_image_msg(array: npt.ArrayLike, encoding: str, stamp_ns: int = 0,
                       frame_id: str = '') -> Image:
    """
    Return ``array`` as a ``sensor_msgs/Image`` (little-endian, unpadded rows).

    :param array: HxW (mono, bayer raw, 16UC1, 32FC1) or HxWxC in the channel order of
        ``encoding``. For the YUV 4:2:2 encodings ('uyvy'/'yuv422', 'yuyv'/'yuv422_yuy2') either
        the packed HxWx2 uint8 bytes as they go on the wire, or an HxWx3 uint8 BGR image that is
        encoded with OpenCV (BT.601; W must be even).
    :param encoding: one of ``IMAGE_ENCODINGS``.
    :param stamp_ns: header stamp, ns.
    :raises errors.MessageError: on an unknown encoding.
    :raises ValueError: if the array's shape or dtype does not fit the encoding.
    """
    dtype, channels = _encoding_info(encoding)
    image = np.asarray(array)
    if channels == 2 and image.ndim == 3 and image.shape[2] == 3:
        if image.dtype != np.uint8 or image.shape[1] % 2:
            raise ValueError(f'BGR to {encoding} needs uint8 and an even width, got '
                             f'{image.dtype} {image.shape}')
        image = cv2.cvtColor(np.ascontiguousarray(image), _BGR_TO_YUV[encoding])
    expected = image.shape[:2] + ((channels,) if channels > 1 else ())
    # Any byte order is accepted: astype below writes little-endian.
    if (image.ndim not in (2, 3) or image.shape != expected
            or image.dtype.newbyteorder('=') != dtype):
        raise ValueError(f'{encoding} needs an array of {dtype} shaped HxW'
                         f'{"x%d" % channels if channels > 1 else ""}, got {image.dtype} '
                         f'{image.shape}')
    msg = Image(check_fields=True)  # keeps the data array as is (see __init__.py)
    set_header(msg, stamp_ns, frame_id)
    msg.height, msg.width = int(image.shape[0]), int(image.shape[1])
    msg.encoding = encoding
    # Multi-byte pixels go on the wire in little-endian order (is_bigendian = 0).
    msg.is_bigendian = 0
    msg.step = msg.width * channels * dtype.itemsize
    msg.data = bytes_array(image.astype(dtype.newbyteorder('<'), copy=False))
    return msg


def _image_view(msg: Any) -> tuple[np.ndarray, str]:
    """Return the message's pixels as a strided view (no copy unless big-endian) and encoding."""
    encoding = str(msg.encoding)
    dtype, channels = _encoding_info(encoding)
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    row_bytes = width * channels * dtype.itemsize
    if step < row_bytes:
        raise errors.MessageError(
            f'{encoding} image step {step} < width {width} x {channels * dtype.itemsize} '
            f'bytes per pixel = {row_bytes}')
    buffer = msg.data
    size = len(buffer)
    if size < step * height:
        raise errors.MessageError(
            f'{encoding} image data has {size} bytes < step {step} x height {height} = '
            f'{step * height}')
    big = bool(msg.is_bigendian) and dtype.itemsize > 1
    wire_dtype = dtype.newbyteorder('>' if big else '<')
    shape: tuple[int, ...] = (height, width, channels)
    strides: tuple[int, ...] = (step, channels * dtype.itemsize, dtype.itemsize)
    if channels == 1:
        shape, strides = shape[:2], strides[:2]
    if height * width == 0:
        return np.zeros(shape, dtype), encoding
    # np.ndarray over the message's own buffer: a view, so no pixel is copied.
    view = np.ndarray(shape, wire_dtype, buffer=buffer, strides=strides)
    return (view.astype(dtype) if big else view), encoding


def image_msg_to_array(msg: Any) -> np.ndarray:
    """
    Return an Image's pixels in their native layout, sharing memory with ``msg.data``.

    The view is writable for rclpy messages (writes change the message) and read-only for
    rosbags messages.

    Layout: HxW for one-channel encodings (mono8, mono16, 16UC1, 32FC1 and bayer raw), HxWxC in
    the encoding's channel order otherwise; YUV 4:2:2 ('uyvy'/'yuv422', 'yuyv'/'yuv422_yuy2')
    stays packed as HxWx2 uint8 (use :func:`image_msg_to_bgr` to decode it). Row padding is
    skipped with strides, so the view may not be C-contiguous. Big-endian 16-bit data is the
    one case that is copied, into native byte order.

    :param msg: ``sensor_msgs/Image`` from rclpy or rosbags.
    :raises errors.MessageError: on an unknown encoding, a step too small for the width or
        data too short for step x height.
    """
    return _image_view(msg)[0]


def image_msg_to_bgr(msg: Any) -> npt.NDArray[np.uint8]:
    """
    Return an Image as a C-contiguous HxWx3 uint8 BGR array.

    bgr8 without row padding is returned without copying: it shares memory with ``msg.data``
    and is read-only for rosbags messages (copy it before drawing on it).
    16-bit images are scaled to 8 bits over their full range (x 255 / 65535, as cv_bridge
    does); YUV 4:2:2 is decoded with OpenCV's BT.601 tables and bayer raw is demosaiced with
    OpenCV's bilinear method.

    :raises errors.MessageError: on a malformed message or a 32FC1 (depth) image.
    """
    image, encoding = _image_view(msg)
    if encoding == '32FC1':
        raise errors.MessageError('32FC1 is a depth or float image, not convertible to BGR')
    if image.dtype == np.uint16:
        image = cv2.convertScaleAbs(np.ascontiguousarray(image), alpha=255.0 / 65535.0)
    image = np.ascontiguousarray(image)
    if encoding in ('bgr8', 'bgr16', '8UC3'):
        return image
    if encoding in _YUV_TO_BGR:
        return cv2.cvtColor(image, _YUV_TO_BGR[encoding])
    if encoding in _BAYER_TO_BGR:
        return cv2.cvtColor(image, _BAYER_TO_BGR[encoding])
    codes = {'rgb8': cv2.COLOR_RGB2BGR, 'rgb16': cv2.COLOR_RGB2BGR, 'bgra8': cv2.COLOR_BGRA2BGR,
             'rgba8': cv2.COLOR_RGBA2BGR}
    return cv2.cvtColor(image, codes.get(encoding, cv2.COLOR_GRAY2BGR))
