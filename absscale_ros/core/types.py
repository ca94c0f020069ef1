"""Plain data shared by the pipeline stages (numpy arrays, no ROS)."""
from dataclasses import dataclass, field, replace

import numpy as np
import numpy.typing as npt

DISTORTION_MODELS = ('none', 'plumb_bob', 'rational_polynomial', 'equidistant')


@dataclass(frozen=True, eq=False)
class CameraModel:
    """
    Pinhole camera with optional lens distortion, as in sensor_msgs/CameraInfo.

    :param width: image width, px.
    :param height: image height, px.
    :param K: (3, 3) float64 intrinsic matrix, px.
    :param dist: (N,) float64 distortion coefficients in the ROS order of ``distortion_model``
        (plumb_bob: k1 k2 p1 p2 k3; rational_polynomial: k1 k2 p1 p2 k3 k4 k5 k6;
        equidistant: k1 k2 k3 k4).
    :param distortion_model: one of ``DISTORTION_MODELS``.
    """

    width: int
    height: int
    K: npt.NDArray[np.float64]
    dist: npt.NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    distortion_model: str = 'none'

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=np.float64)
        dist = np.asarray(self.dist, dtype=np.float64).ravel()
        if K.shape != (3, 3):
            raise ValueError(f'K must be 3x3, got shape {K.shape}')
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f'image size must be positive, got {self.width}x{self.height}')
        if self.distortion_model not in DISTORTION_MODELS:
            raise ValueError(f'unknown distortion model {self.distortion_model!r}')
        object.__setattr__(self, 'K', K)
        object.__setattr__(self, 'dist', dist)

    @property
    def has_distortion(self) -> bool:
        return self.distortion_model != 'none' and bool(np.any(self.dist != 0.0))

    def resized(self, width: int, height: int) -> 'CameraModel':
        """Return the model of the same camera with its image resized to ``width`` x ``height``."""
        sx, sy = width / self.width, height / self.height
        K = self.K.copy()
        K[0, :] *= sx
        K[1, :] *= sy
        # Pixel centres: ROS/OpenCV put pixel i's centre at i, so cx' = (cx + 0.5) * s - 0.5.
        K[0, 2] = (self.K[0, 2] + 0.5) * sx - 0.5
        K[1, 2] = (self.K[1, 2] + 0.5) * sy - 0.5
        return replace(self, width=width, height=height, K=K)
