"""sensor_msgs/CompressedImage (JPEG, PNG) to numpy and back."""
from typing import Any

from absscale_ros.conversions.stamps import bytes_array, set_header
from absscale_ros.core import errors
import cv2
import numpy as np
import numpy.typing as npt
from sensor_msgs.msg import CompressedImage


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
    set_header(msg, stamp_ns, frame_id)
    msg.format = f'{encoding}; {fmt} compressed {encoding}'
    msg.data = bytes_array(buffer)
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
