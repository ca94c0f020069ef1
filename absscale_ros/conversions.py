"""
The only module that turns ROS messages into numpy arrays and back.

Readers are duck-typed: they work on rclpy message instances (``data`` is an ``array.array``)
and on messages deserialized by rosbags (``data`` is a numpy array), since both expose the same
field names. Expected failures (malformed or unsupported messages) raise
:class:`absscale_ros.core.errors.MessageError` with the numbers involved.

Speed notes (1280x720 bgr8, see ``test/bench/bench_conversions.py``): readers wrap
``msg.data``'s buffer in a strided ``np.ndarray`` (no copy), so a returned array shares memory
with the message (and is read-only for rosbags messages). Writers fill ``data`` with an
``array.array('B')`` built by ``frombytes`` from the array's buffer: one copy (0.1 ms),
which the generated setter stores as is only in a message made with ``check_fields=True``
(else it copies it again: 0.25 instead of 0.11 ms a frame). Assigning ``array.tobytes()``
costs two copies (1.7 ms) and, with ``ROS_PYTHON_CHECK_FIELDS=1``, a per-byte check (270 ms);
a memoryview or an ndarray goes through ``array.array('B', iterable)`` (130 ms or more).
"""
import array
from collections.abc import Mapping, Sequence
from types import MappingProxyType
from typing import Any

from absscale_ros.core import errors
from absscale_ros.core.keyframes import TrackedStep
from absscale_ros.core.types import CameraModel
from builtin_interfaces.msg import Time
import cv2
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, TransformStamped
from nav_msgs.msg import Path
import numpy as np
import numpy.typing as npt
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, PointCloud2, PointField
from std_msgs.msg import Float64MultiArray, Header, MultiArrayDimension

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
    msg = Image(check_fields=True)  # keeps the data array as is (see the module doc)
    _header(msg, stamp_ns, frame_id)
    msg.height, msg.width = int(image.shape[0]), int(image.shape[1])
    msg.encoding = encoding
    # Multi-byte pixels go on the wire in little-endian order (is_bigendian = 0).
    msg.is_bigendian = 0
    msg.step = msg.width * channels * dtype.itemsize
    msg.data = _bytes_array(image.astype(dtype.newbyteorder('<'), copy=False))
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


def compressed_format(msg: Any) -> str:
    """
    Return the compression named in a CompressedImage's format string.

    image_transport writes 'jpeg', 'png' or '<enc>; <jpeg|png> compressed <enc>'.

    :returns: 'jpeg' (also for 'jpg'), 'png', '' if the format is empty, 'compresseddepth' for
        the depth plugin, or else the lower-cased format word (e.g. 'theora').
    """
    fmt = str(msg.format).lower()
    if 'compresseddepth' in fmt:
        return 'compresseddepth'
    words = fmt.split(';')[-1].split()
    kind = words[0] if words else ''
    return 'jpeg' if kind == 'jpg' else kind


def compressed_bytes(msg: Any) -> npt.NDArray[np.uint8]:
    """Return a CompressedImage's payload as a 1-D uint8 view on ``msg.data`` (no copy)."""
    return np.frombuffer(msg.data, np.uint8)


def image_geometry(msg: Any) -> tuple[int, int, str]:
    """Return an Image's ``(width, height, encoding)`` without touching its pixels."""
    return int(msg.width), int(msg.height), str(msg.encoding)


def _compressed_buffer(msg: Any) -> npt.NDArray[np.uint8]:
    # The depth plugin's 'compressedDepth' payload starts with a private header we do not parse.
    if compressed_format(msg) not in ('', 'jpeg', 'png'):
        raise errors.MessageError(f'unsupported CompressedImage format {msg.format!r}; '
                                  "expected 'jpeg' or 'png'")
    data = compressed_bytes(msg)
    if data.size == 0:
        raise errors.MessageError(f'CompressedImage ({msg.format!r}) has no data')
    return data


def _decode(msg: Any, flags: int) -> np.ndarray:
    data = _compressed_buffer(msg)
    image = cv2.imdecode(data, flags)
    if image is None:
        raise errors.MessageError(f'could not decode {data.size} bytes of CompressedImage '
                                  f'({msg.format!r}), first bytes {bytes(data[:8]).hex()}')
    return image


def compressed_msg_to_bgr(msg: Any) -> npt.NDArray[np.uint8]:
    """
    Return a JPEG or PNG CompressedImage as HxWx3 uint8 BGR.

    Grey images are expanded to three channels and 16-bit PNGs reduced to 8 bits. EXIF
    orientation is ignored: camera frames are used as the sensor saw them.

    :param msg: ``sensor_msgs/CompressedImage`` from rclpy or rosbags.
    :raises errors.MessageError: on an unsupported format or undecodable data.
    """
    return _decode(msg, cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)


def compressed_msg_to_array(msg: Any) -> np.ndarray:
    """
    Return a CompressedImage decoded without changing its depth or channel count.

    :returns: HxW uint8 or uint16 for grey images (a 16-bit PNG stays uint16), HxWx3 in BGR
        order or HxWx4 in BGRA order for colour ones, whatever encoding the publisher started
        from (compressed_image_transport always compresses colour as BGR).
    :raises errors.MessageError: on an unsupported format or undecodable data.
    """
    return _decode(msg, cv2.IMREAD_UNCHANGED)


# --------------------------------------------------------------------------------------------
# Camera info
# --------------------------------------------------------------------------------------------

# Number of D coefficients ROS writes for each model ('none' goes out as zero plumb_bob).
_DIST_SIZES = {'plumb_bob': 5, 'rational_polynomial': 8, 'equidistant': 4}


def _checked_dist(model: str, dist: npt.NDArray[np.float64]) -> tuple[str, np.ndarray]:
    """Return the CameraModel distortion model and coefficients for a CameraInfo's D."""
    if dist.size == 0:
        return 'none', dist
    if model in ('', 'none'):
        if np.any(dist != 0.0):
            raise errors.MessageError(f'CameraInfo has {dist.size} non-zero D coefficients '
                                      'but no distortion_model')
        return 'none', np.zeros(0)
    if model not in _DIST_SIZES:
        raise errors.MessageError(f'unsupported distortion_model {model!r}; supported: '
                                  f'{", ".join(_DIST_SIZES)}')
    size = _DIST_SIZES[model]
    if model == 'plumb_bob' and dist.size == 4:
        dist = np.append(dist, 0.0)  # k1 k2 p1 p2 without k3, as some drivers write it
    elif dist.size > size and not np.any(dist[size:] != 0.0):
        dist = dist[:size]  # trailing zeros some drivers pad D with
    if dist.size != size:
        raise errors.MessageError(f'{model} needs {size} D coefficients, got {dist.size}')
    return model, dist


def _apply_roi_binning(msg: Any, width: int, height: int,
                       K: np.ndarray) -> tuple[int, int, np.ndarray]:
    """Return the size and K of the published image after ROI crop and binning."""
    # As image_geometry does: the calibration is at full resolution, the image may not be.
    roi = msg.roi
    bin_x, bin_y = max(int(msg.binning_x), 1), max(int(msg.binning_y), 1)
    K = K.copy()
    if int(roi.width) and int(roi.height):
        K[0, 2] -= int(roi.x_offset)
        K[1, 2] -= int(roi.y_offset)
        width, height = int(roi.width), int(roi.height)
    K[0, :] /= bin_x
    K[1, :] /= bin_y
    return width // bin_x, height // bin_y, K


def camera_info_to_model(msg: Any) -> CameraModel:
    """
    Return the camera model of a ``sensor_msgs/CameraInfo``.

    Supports 'plumb_bob', 'rational_polynomial' and 'equidistant'; an empty D (or an empty or
    'none' model with all-zero D) gives 'none'. ROI and binning, when set, are applied to the
    size and K, as image_geometry does. R and P are ignored: frames are used unrectified.

    :raises errors.MessageError: if the size is zero, K is all zeros (uncalibrated camera) or
        has a non-positive focal length, K or D hold NaN or inf, or D does not fit the model.
    """
    width, height = int(msg.width), int(msg.height)
    if width <= 0 or height <= 0:
        raise errors.MessageError(f'CameraInfo image size is {width}x{height}')
    K = np.asarray(msg.k, dtype=np.float64).reshape(3, 3)
    dist = np.asarray(msg.d, dtype=np.float64).ravel()
    if not np.all(np.isfinite(K)) or not np.all(np.isfinite(dist)):
        raise errors.MessageError(f'CameraInfo has NaN or inf: K={K.ravel().tolist()}, '
                                  f'D={dist.tolist()}')
    if not np.any(K != 0.0):
        raise errors.MessageError('CameraInfo K is all zeros: the camera is not calibrated')
    if K[0, 0] <= 0.0 or K[1, 1] <= 0.0:
        raise errors.MessageError(f'CameraInfo K has fx={K[0, 0]}, fy={K[1, 1]}: focal '
                                  'lengths must be positive')
    model, dist = _checked_dist(str(msg.distortion_model), dist)
    width, height, K = _apply_roi_binning(msg, width, height, K)
    try:
        return CameraModel(width=width, height=height, K=K, dist=dist, distortion_model=model)
    except ValueError as err:  # e.g. a ROI narrower than the binning
        raise errors.MessageError(f'CameraInfo gives an invalid camera: {err}') from None


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


# --------------------------------------------------------------------------------------------
# Point clouds
# --------------------------------------------------------------------------------------------

_FIELD_DTYPES: dict[int, np.dtype] = {
    PointField.INT8: np.dtype(np.int8), PointField.UINT8: np.dtype(np.uint8),
    PointField.INT16: np.dtype(np.int16), PointField.UINT16: np.dtype(np.uint16),
    PointField.INT32: np.dtype(np.int32), PointField.UINT32: np.dtype(np.uint32),
    PointField.FLOAT32: np.dtype(np.float32), PointField.FLOAT64: np.dtype(np.float64),
}
_DTYPE_FIELDS = {dtype: code for code, dtype in _FIELD_DTYPES.items()}


def _cloud_dtype(msg: Any) -> np.dtype:
    """Return the structured dtype of one point on the wire (itemsize = point_step)."""
    order = '>' if msg.is_bigendian else '<'
    point_step = int(msg.point_step)
    names, formats, offsets = [], [], []
    for field in msg.fields:
        code, offset, count = int(field.datatype), int(field.offset), int(field.count)
        if code not in _FIELD_DTYPES:
            raise errors.MessageError(f'PointCloud2 field {field.name!r} has unknown datatype '
                                      f'{code} (1..8 are INT8..FLOAT64)')
        base = _FIELD_DTYPES[code].newbyteorder(order)
        # count 0 is written by some drivers for a scalar; ROS means 1 element either way.
        dtype = np.dtype((base, (count,))) if count > 1 else base
        if offset + dtype.itemsize > point_step:
            raise errors.MessageError(
                f'PointCloud2 field {field.name!r} at offset {offset} with {dtype.itemsize} '
                f'bytes does not fit point_step {point_step}')
        names.append(str(field.name))
        formats.append(dtype)
        offsets.append(offset)
    try:
        return np.dtype({'names': names, 'formats': formats, 'offsets': offsets,
                         'itemsize': point_step})
    except ValueError as err:  # duplicate or empty names
        raise errors.MessageError(f'PointCloud2 fields {names} are invalid: {err}') from None


def cloud_msg_to_array(msg: Any, skip_nans: bool = False) -> np.ndarray:
    """
    Return a ``sensor_msgs/PointCloud2`` as a structured numpy array.

    :param msg: PointCloud2 from rclpy or rosbags.
    :param skip_nans: drop points whose x, y or z (those present) is not finite; by default
        every point is kept, NaNs included, whatever ``is_dense`` says.
    :returns: (height * width,) array, organised clouds flattened row-major, with the
        message's field names, offsets and dtypes (count > 1 as a subarray) and itemsize
        point_step. Little-endian clouds without row padding are a view on ``msg.data``;
        big-endian ones are copied into native byte order.
    :raises errors.MessageError: on an unknown field type, a field beyond point_step,
        row_step < width x point_step or data length != row_step x height.
    """
    dtype = _cloud_dtype(msg)
    height, width = int(msg.height), int(msg.width)
    point_step, row_step = int(msg.point_step), int(msg.row_step)
    if row_step < width * point_step:
        raise errors.MessageError(f'PointCloud2 row_step {row_step} < width {width} x '
                                  f'point_step {point_step} = {width * point_step}')
    size = len(msg.data)
    if size != row_step * height:
        raise errors.MessageError(f'PointCloud2 data has {size} bytes != row_step {row_step} '
                                  f'x height {height} = {row_step * height}')
    if height * width == 0:
        points = np.zeros(0, dtype)
    elif point_step == 0:
        raise errors.MessageError(f'PointCloud2 has {height * width} points but point_step 0')
    else:
        rows = np.ndarray((height, width), dtype, buffer=msg.data, strides=(row_step, point_step))
        # reshape copies only when rows are padded; unpadded clouds stay a view.
        points = rows.reshape(-1)
    if msg.is_bigendian:
        points = points.astype(dtype.newbyteorder('='))
    if skip_nans and points.shape[0]:
        keep = np.ones(points.shape[0], dtype=bool)
        for axis in ('x', 'y', 'z'):
            if axis in points.dtype.names:
                values = points[axis]
                keep &= np.isfinite(values.reshape(values.shape[0], -1)).all(axis=1)
        points = points[keep]
    return points


def _fields_from_dtype(dtype: np.dtype) -> list[PointField]:
    fields = []
    for name in dtype.names or ():
        field_dtype, offset = dtype.fields[name][:2]
        base, shape = field_dtype.base, field_dtype.shape
        code = _DTYPE_FIELDS.get(base.newbyteorder('='))
        if code is None or base.names is not None:
            raise ValueError(f'field {name!r} has dtype {field_dtype}, which PointCloud2 '
                             'cannot carry (INT8..FLOAT64 scalars or fixed arrays only)')
        fields.append(PointField(name=name, offset=int(offset), datatype=code,
                                 count=int(np.prod(shape, dtype=np.int64))))
    return fields


def array_to_cloud_msg(array: np.ndarray, stamp_ns: int = 0,
                       frame_id: str = 'map') -> PointCloud2:
    """
    Return a structured array as an unorganised PointCloud2 (height 1, little-endian).

    Field offsets and point_step come from the dtype, so padding in it is kept. ``is_dense`` is
    True when every x, y and z present is finite.

    :param array: structured array of any shape (flattened row-major) whose fields are
        INT8..FLOAT64 scalars or fixed-size subarrays (sent with count > 1).
    :raises ValueError: if ``array`` is not structured or a field type has no PointField code.
    """
    points = np.asarray(array)
    if points.dtype.names is None:
        raise ValueError(f'array_to_cloud_msg needs a structured array, got {points.dtype}')
    fields = _fields_from_dtype(points.dtype)
    points = points.reshape(-1).astype(points.dtype.newbyteorder('<'), copy=False)
    msg = PointCloud2()
    _header(msg, stamp_ns, frame_id)
    msg.height, msg.width = 1, int(points.shape[0])
    msg.fields = fields
    msg.is_bigendian = False
    msg.point_step = int(points.dtype.itemsize)
    msg.row_step = msg.point_step * msg.width
    msg.data = _bytes_array(points)
    msg.is_dense = all(bool(np.isfinite(points[axis]).all())
                       for axis in ('x', 'y', 'z') if axis in points.dtype.names)
    return msg


def pack_rgb(colors: npt.ArrayLike) -> npt.NDArray[np.float32]:
    """
    Return (N, 3) uint8 RGB colours packed as PCL does: 0x00RRGGBB bit-cast to float32.

    :raises ValueError: if ``colors`` is not (N, 3) or outside [0, 255].
    """
    colors = np.asarray(colors)
    if colors.ndim != 2 or colors.shape[1] != 3:
        raise ValueError(f'colors must be (N, 3) RGB, got shape {colors.shape}')
    if colors.size and (colors.min() < 0 or colors.max() > 255):
        raise ValueError(f'colors must be in [0, 255], got [{colors.min()}, {colors.max()}]')
    rgb = colors.astype(np.uint32)
    packed = (rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]
    return packed.view(np.float32)


def unpack_rgb(packed: npt.ArrayLike) -> npt.NDArray[np.uint8]:
    """
    Return (N, 3) uint8 RGB from PCL-packed colours (float32 bit patterns or uint32).

    The top byte (alpha in 'rgba' fields) is ignored.
    """
    packed = np.asarray(packed).reshape(-1)
    if packed.dtype.kind == 'f':
        if packed.dtype.itemsize != 4:
            raise ValueError(f'packed colours must be float32 or uint32, got {packed.dtype}')
        bits = packed.astype(np.float32, copy=False).view(np.uint32)
    else:
        bits = packed.astype(np.uint32, copy=False)
    shifts = np.array([16, 8, 0], dtype=np.uint32)
    return ((bits[:, None] >> shifts) & 0xFF).astype(np.uint8)


def xyz_rgb_to_cloud_msg(points: npt.ArrayLike, colors: npt.ArrayLike | None = None,
                         stamp_ns: int = 0, frame_id: str = 'map',
                         extra: Mapping[str, npt.ArrayLike] | None = None) -> PointCloud2:
    """
    Return points (and colours and extra fields) as a PointCloud2 RViz can show.

    :param points: (N, 3) positions, m in ``frame_id``; sent as float32 x, y, z.
    :param colors: (N, 3) uint8 RGB, sent as a packed float32 'rgb' field (see
        :func:`pack_rgb`), or None for no colour.
    :param extra: more per-point fields by name, each (N,) or (N, k) of a PointField type,
        e.g. ``{'vertex_id': ids.astype(np.int32)}``.
    :raises ValueError: on shapes that do not match N or names that collide.
    """
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f'points must be (N, 3), got shape {points.shape}')
    n = points.shape[0]
    columns: dict[str, np.ndarray] = {axis: points[:, i].astype(np.float32)
                                      for i, axis in enumerate('xyz')}
    if colors is not None:
        columns['rgb'] = pack_rgb(colors)
    for name, values in (extra or {}).items():
        values = np.asarray(values)
        if name in columns:
            raise ValueError(f'extra field {name!r} collides with a standard field')
        if values.shape[:1] != (n,) or values.ndim > 2:
            raise ValueError(f'extra field {name!r} must be ({n},) or ({n}, k), '
                             f'got {values.shape}')
        columns[name] = values
    if colors is not None and columns['rgb'].shape[0] != n:
        raise ValueError(f'colors has {columns["rgb"].shape[0]} rows, points has {n}')
    dtype = np.dtype([(name, values.dtype, values.shape[1:]) for name, values in columns.items()])
    cloud = np.empty(n, dtype)
    for name, values in columns.items():
        cloud[name] = values
    return array_to_cloud_msg(cloud, stamp_ns=stamp_ns, frame_id=frame_id)


# --------------------------------------------------------------------------------------------
# Paths
# --------------------------------------------------------------------------------------------

_UNIT_QUAT_TOL = 1e-3  # float32 round trips and printed YAML stay well inside this


def path_msg_to_poses(msg: Any) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """
    Return a ``nav_msgs/Path`` as poses and stamps.

    :returns: poses (N, 7) float64 ``[x y z qx qy qz qw]`` (position in the path's frame, quat_xyzw
        renormalised to unit length) and stamps_ns (N,) int64, each pose's own header stamp.
    :raises errors.MessageError: if a quaternion is not unit length (within 1e-3) or a value is
        not finite.
    """
    count = len(msg.poses)
    poses = np.empty((count, 7), dtype=np.float64)
    stamps_ns = np.empty(count, dtype=np.int64)
    for i, stamped in enumerate(msg.poses):
        p, q = stamped.pose.position, stamped.pose.orientation
        poses[i] = (p.x, p.y, p.z, q.x, q.y, q.z, q.w)
        stamps_ns[i] = stamp_to_ns(stamped.header.stamp)
    if not np.all(np.isfinite(poses)):
        bad = int(np.flatnonzero(~np.isfinite(poses).all(axis=1))[0])
        raise errors.MessageError(f'Path pose {bad} has NaN or inf: {poses[bad].tolist()}')
    norms = np.linalg.norm(poses[:, 3:], axis=1)
    off = np.flatnonzero(np.abs(norms - 1.0) > _UNIT_QUAT_TOL)
    if off.size:
        raise errors.MessageError(f'Path pose {int(off[0])} quaternion has norm '
                                  f'{norms[off[0]]:.6g}, not 1 ({off.size} of {count} poses)')
    poses[:, 3:] /= norms[:, None]
    return poses, stamps_ns


def poses_to_path_msg(poses: npt.ArrayLike, stamps_ns: npt.ArrayLike, frame_id: str = 'map',
                      stamp_ns: int | None = None) -> Path:
    """
    Return poses as a ``nav_msgs/Path``.

    :param poses: (N, 7) ``[x y z qx qy qz qw]``, position in m, quat_xyzw unit length.
    :param stamps_ns: (N,) stamp of each pose, ns.
    :param stamp_ns: the path's header stamp; by default the last pose's stamp (0 if empty).
    :raises ValueError: on mismatched shapes, non-finite values or non-unit quaternions.
    """
    poses = np.asarray(poses, dtype=np.float64)
    stamps = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
    if poses.ndim != 2 or poses.shape[1] != 7 or poses.shape[0] != stamps.shape[0]:
        raise ValueError(f'need poses (N, 7) and stamps (N,), got {poses.shape} and '
                         f'{stamps.shape}')
    norms = np.linalg.norm(poses[:, 3:], axis=1)
    if not np.all(np.isfinite(poses)) or np.any(np.abs(norms - 1.0) > _UNIT_QUAT_TOL):
        raise ValueError('poses must be finite with unit quat_xyzw')
    msg = Path()
    if stamp_ns is None:
        stamp_ns = int(stamps[-1]) if stamps.size else 0
    _header(msg, stamp_ns, frame_id)
    out = []
    for pose, pose_stamp_ns in zip(poses.tolist(), stamps.tolist()):
        stamped = PoseStamped()
        _header(stamped, pose_stamp_ns, frame_id)
        position, orientation = stamped.pose.position, stamped.pose.orientation
        position.x, position.y, position.z = pose[:3]
        orientation.x, orientation.y, orientation.z, orientation.w = pose[3:]
        out.append(stamped)
    msg.poses = out
    return msg


# --------------------------------------------------------------------------------------------
# Diagnostics
# --------------------------------------------------------------------------------------------

_LEVELS = {'ok': DiagnosticStatus.OK, 'warn': DiagnosticStatus.WARN,
           'error': DiagnosticStatus.ERROR, 'stale': DiagnosticStatus.STALE}


def _level_byte(level: str | bytes | int) -> bytes:
    if isinstance(level, str):
        if level.lower() not in _LEVELS:
            raise ValueError(f'diagnostic level must be one of {list(_LEVELS)}, got {level!r}')
        return _LEVELS[level.lower()]
    value = level[0] if isinstance(level, bytes) and len(level) == 1 else level
    if not isinstance(value, int) or not 0 <= value <= 3:
        raise ValueError(f'diagnostic level must be 0..3 (OK..STALE), got {level!r}')
    return bytes([value])


def _format_value(value: object) -> str:
    if isinstance(value, (bool, np.bool_)):
        return str(bool(value))
    if isinstance(value, (float, np.floating)):
        return format(float(value), '.6g')  # compact: 0.1 not 0.1000000000000000055...
    if isinstance(value, np.integer):
        return str(int(value))
    return str(value)


def diagnostic_status(name: str, level: str | bytes | int, message: str,
                      values: Mapping[str, object] = MappingProxyType({}),
                      hardware_id: str = 'absscale') -> DiagnosticStatus:
    """
    Return a ``diagnostic_msgs/DiagnosticStatus``.

    :param level: 'ok', 'warn', 'error' or 'stale', or the message's byte constants
        (``DiagnosticStatus.OK``...) or their integer values.
    :param values: key/value pairs; floats are written with 6 significant digits.
    :raises ValueError: on an unknown level.
    """
    return DiagnosticStatus(
        level=_level_byte(level), name=name, message=message, hardware_id=hardware_id,
        values=[KeyValue(key=str(key), value=_format_value(value))
                for key, value in values.items()])


def diagnostic_array(statuses: Sequence[DiagnosticStatus], stamp_ns: int) -> DiagnosticArray:
    """Return statuses in a ``diagnostic_msgs/DiagnosticArray`` stamped ``stamp_ns``."""
    msg = DiagnosticArray()
    _header(msg, stamp_ns, '')
    msg.status = list(statuses)
    return msg


def diagnostic_summary(msg: Any) -> dict[str, dict[str, Any]]:
    """Status name -> ``{level (int 0..3), message, values}`` of a DiagnosticArray."""
    return {str(st.name): {'level': _level_byte(st.level)[0], 'message': str(st.message),
                           'values': diagnostic_values(st)} for st in msg.status}


def ack_to_msg(text: str, stamp: Any) -> Header:
    """The step-mode acknowledgement ``text`` (see core/replay.Ack) for a message's stamp."""
    return Header(stamp=stamp, frame_id=text)


def end_of_bag_msg(stamp_ns: int) -> Header:
    """The lossless replay's end-of-bag message, stamped after every frame (``bag_replay``)."""
    return Header(stamp=ns_to_stamp(stamp_ns), frame_id='end_of_bag')


def ack_from_msg(msg: Any) -> tuple[str, int]:
    """Inverse of :func:`ack_to_msg`: (text, stamp in ns)."""
    return str(msg.frame_id), stamp_to_ns(msg.stamp)


def diagnostic_values(status: Any) -> dict[str, str]:
    """Return a DiagnosticStatus's key/value pairs as a dict (the last one wins on repeats)."""
    return {str(pair.key): str(pair.value) for pair in status.values}


SCALE_LAYOUT = ('factor', 'sigma', 'ci_low', 'ci_high', 'edges', 'objects')


def scale_to_msg(values: Mapping[str, float]) -> Float64MultiArray:
    """
    Return the metric scale as a Float64MultiArray labelled ``factor,sigma,ci_low,...``.

    No standard message holds a scalar with its uncertainty; a labelled array keeps
    ``ros2 topic echo`` readable and needs no custom interface package.
    """
    msg = Float64MultiArray()
    msg.layout.dim = [MultiArrayDimension(label=','.join(SCALE_LAYOUT),
                                          size=len(SCALE_LAYOUT), stride=len(SCALE_LAYOUT))]
    msg.data = [float(values[k]) for k in SCALE_LAYOUT]
    return msg


def scale_from_msg(msg: Any) -> dict[str, float]:
    """Inverse of :func:`scale_to_msg`; MessageError if the labels are not ours."""
    labels = msg.layout.dim[0].label.split(',') if len(msg.layout.dim) else []
    if labels != list(SCALE_LAYOUT) or len(msg.data) != len(SCALE_LAYOUT):
        raise errors.MessageError(f'scale message has labels {labels}, want {SCALE_LAYOUT}')
    return dict(zip(SCALE_LAYOUT, (float(v) for v in msg.data)))


def scaled_cloud_msg(msg: Any, factor: float, stamp_ns: int, frame_id: str) -> PointCloud2:
    """Return ``msg`` with x, y, z multiplied by ``factor``; every other field kept."""
    points = cloud_msg_to_array(msg).copy()
    for axis in ('x', 'y', 'z'):
        if axis not in (points.dtype.names or ()):
            raise errors.MessageError(f'cloud has no {axis!r} field to scale')
        points[axis] = points[axis] * factor
    return array_to_cloud_msg(points, stamp_ns, frame_id)


def dense_cloud_msg(points: npt.ArrayLike, colors: npt.ArrayLike, normals: npt.ArrayLike,
                    stamp_ns: int = 0, frame_id: str = 'map') -> PointCloud2:
    """
    The dense cloud: float32 ``x y z``, packed ``rgb`` and ``normal_x normal_y normal_z``
    (PCL's PointXYZRGBNormal names, which RViz and Open3D's ROS readers know).
    """
    normals = np.asarray(normals, dtype=np.float32)
    if normals.shape != np.shape(points):
        raise ValueError(f'normals {normals.shape} do not match points {np.shape(points)}')
    return xyz_rgb_to_cloud_msg(points, colors, stamp_ns, frame_id, extra={
        f'normal_{a}': normals[:, i] for i, a in enumerate('xyz')})


def cloud_msg_to_xyz_rgb_normals(msg: Any) -> tuple[
        npt.NDArray[np.float64], npt.NDArray[np.uint8] | None, npt.NDArray[np.float64] | None]:
    """Finite points of a PointCloud2 as (N, 3) xyz, and its (N, 3) rgb and normals if any."""
    pts = cloud_msg_to_array(msg, skip_nans=True)
    names = pts.dtype.names or ()
    xyz = np.stack([pts[a] for a in 'xyz'], axis=1).astype(np.float64)
    rgb = unpack_rgb(pts['rgb']) if 'rgb' in names else None
    normals = np.stack([pts[f'normal_{a}'] for a in 'xyz'], axis=1).astype(np.float64) \
        if 'normal_x' in names else None
    return xyz, rgb, normals


def cloud_stamp_and_size(msg: Any) -> tuple[int, int]:
    """(header stamp in ns, number of points) of a PointCloud2, without decoding it."""
    return stamp_to_ns(msg.header.stamp), int(msg.width) * int(msg.height)


def _keyframe_frame(stamp_ns: int) -> str:
    return f'keyframe_{stamp_ns}'


def tracked_step_to_msg(step: TrackedStep | None, stamp_ns: int) -> TransformStamped:
    """
    A keyframe's tracked motion as the pose of its camera (``child_frame_id``
    ``keyframe_<stamp_ns>``) in the previous keyframe's camera frame (``header.frame_id``
    ``keyframe_<ref_stamp_ns>``); translation in units of the previous keyframe's median scene
    depth (scale-free). An unknown step (first keyframe, after a tracking loss) has an empty
    ``header.frame_id``, so every keyframe still gets a message.
    """
    msg = TransformStamped()
    _header(msg, stamp_ns, '' if step is None else _keyframe_frame(step.ref_stamp_ns))
    msg.child_frame_id = _keyframe_frame(stamp_ns)
    if step is None:
        msg.transform.rotation.w = 1.0
        return msg
    t, q = msg.transform.translation, msg.transform.rotation
    t.x, t.y, t.z = (float(v) for v in step.centre)
    from scipy.spatial.transform import Rotation  # here: 0.36 s to import, in two nodes only
    q.x, q.y, q.z, q.w = (float(v) for v in Rotation.from_matrix(step.rotation.T).as_quat())
    return msg


def tracked_step_from_msg(msg: Any) -> TrackedStep | None:
    """
    The ``TrackedStep`` of ``tracked_step_to_msg`` (None: unknown step).

    :raises errors.MessageError: on a frame name that is not ``keyframe_<ns>``, or a
        non-finite translation or rotation.
    """
    parent = msg.header.frame_id
    if not parent:
        return None
    prefix, _, ns = parent.rpartition('_')
    t, q = msg.transform.translation, msg.transform.rotation
    centre = np.array([t.x, t.y, t.z], float)
    quat = np.array([q.x, q.y, q.z, q.w], float)
    if prefix != 'keyframe' or not ns.isdigit() or not np.all(np.isfinite(centre)) \
            or not np.isfinite(quat).all() or not np.linalg.norm(quat) > 0.5:
        raise errors.MessageError(f'bad tracked step: frame {parent!r}, translation {centre}, '
                                  f'rotation {quat}')
    from scipy.spatial.transform import Rotation
    return TrackedStep(int(ns), Rotation.from_quat(quat).as_matrix().T, centre)
