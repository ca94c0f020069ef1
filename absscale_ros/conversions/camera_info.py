"""sensor_msgs/CameraInfo to the core CameraModel and back."""
from typing import Any

from absscale_ros.conversions.stamps import set_header
from absscale_ros.core import errors
from absscale_ros.core.types import CameraModel
import numpy as np
import numpy.typing as npt
from sensor_msgs.msg import CameraInfo


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
    set_header(msg, stamp_ns, frame_id)
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
