"""
Camera calibration from a chessboard video, and the ROS calibration YAML file format.

The YAML is the one camera_calibration writes and camera_info_manager reads (image_width,
camera_matrix, distortion_model, ...), so a file from either tool works here and back.
"""
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt
import yaml

from absscale_ros.core.errors import AbsScaleError, DegenerateGeometryError
from absscale_ros.core.types import CameraModel


@dataclass(frozen=True)
class CalibrationConfig:
    """Chessboard calibration settings."""

    inner_corners: tuple[int, int] = (9, 6)  # (columns, rows) of inner corners
    square_m: float = 0.025  # side of one square, m
    max_views: int = 40  # views kept, spread over the video
    min_views: int = 8  # fewer leave the intrinsics poorly determined

    def __post_init__(self) -> None:
        if min(self.inner_corners) < 2 or self.square_m <= 0.0:
            raise ValueError(f'need >= 2x2 inner corners and a positive square size, got '
                             f'{self.inner_corners} and {self.square_m} m')


@dataclass(frozen=True, eq=False)
class Calibration:
    """A calibrated camera and how well the model explains the views (RMS px)."""

    model: CameraModel
    rms_px: float
    views: int


def find_board(gray: npt.NDArray[np.uint8],
               cfg: CalibrationConfig) -> npt.NDArray[np.float32] | None:
    """(N, 1, 2) sub-pixel inner corners of the board in a grey image, or None."""
    found, corners = cv2.findChessboardCorners(
        gray, cfg.inner_corners, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_FAST_CHECK
        | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not found:
        return None
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.01)
    return cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1), criteria)


def calibrate(corners: list[npt.NDArray[np.float32]], size: tuple[int, int],
              cfg: CalibrationConfig) -> Calibration:
    """
    Intrinsics and plumb_bob distortion from board detections in ``size`` = (w, h) images.

    :raises DegenerateGeometryError: with fewer than ``cfg.min_views`` views.
    """
    if len(corners) < cfg.min_views:
        raise DegenerateGeometryError(f'board found in {len(corners)} views < '
                                      f'{cfg.min_views}: move the board around more')
    cols, rows = cfg.inner_corners
    board = np.zeros((rows * cols, 3), np.float32)
    board[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * cfg.square_m
    pick = np.linspace(0, len(corners) - 1, min(cfg.max_views, len(corners))).astype(int)
    rms, K, dist, _, _ = cv2.calibrateCamera([board] * len(pick), [corners[i] for i in pick],
                                             size, None, None)
    model = CameraModel(size[0], size[1], K, np.asarray(dist).ravel()[:5], 'plumb_bob')
    return Calibration(model, float(rms), len(pick))


def _matrix(rows: int, cols: int, data: npt.ArrayLike) -> dict[str, object]:
    return {'rows': rows, 'cols': cols,
            'data': [float(x) for x in np.asarray(data, float).ravel()]}


def model_to_yaml(model: CameraModel, camera_name: str = 'camera') -> str:
    """The ROS calibration YAML text of ``model``."""
    P = np.hstack([model.K, np.zeros((3, 1))])
    dist = model.dist if model.distortion_model != 'none' else np.zeros(5)
    doc = {'image_width': model.width, 'image_height': model.height,
           'camera_name': camera_name, 'camera_matrix': _matrix(3, 3, model.K),
           'distortion_model': 'plumb_bob' if model.distortion_model == 'none'
           else model.distortion_model,
           'distortion_coefficients': _matrix(1, len(dist), dist),
           'rectification_matrix': _matrix(3, 3, np.eye(3)),
           'projection_matrix': _matrix(3, 4, P)}
    return yaml.safe_dump(doc, sort_keys=False)


def model_from_yaml(text: str, source: str = 'calibration YAML') -> CameraModel:
    """
    Parse a ROS calibration YAML.

    :raises AbsScaleError: naming ``source`` and the missing or bad entry.
    """
    try:
        doc = yaml.safe_load(text)
        K = np.array(doc['camera_matrix']['data'], float).reshape(3, 3)
        dist = np.array(doc.get('distortion_coefficients', {}).get('data', []), float)
        name = str(doc.get('distortion_model') or 'plumb_bob') if np.any(dist) else 'none'
        model = CameraModel(int(doc['image_width']), int(doc['image_height']), K, dist, name)
    except (yaml.YAMLError, KeyError, TypeError, ValueError) as err:
        raise AbsScaleError(f'{source}: not a ROS calibration file ({err})') from err
    if not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise AbsScaleError(f'{source}: camera_matrix has no valid focal length')
    return model


def load_calibration_yaml(path: str | Path) -> CameraModel:
    """
    Read a ROS calibration file (what camera_calibration and ``absscale calibrate`` write).

    :raises AbsScaleError: when the file is missing or not such a calibration.
    """
    try:
        text = Path(path).read_text()
    except OSError as err:
        raise AbsScaleError(f'{path}: cannot read the calibration file ({err.strerror})') \
            from err
    return model_from_yaml(text, str(path))
