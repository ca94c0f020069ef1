"""Rays through pixel positions of a camera, and small vector helpers without BLAS."""
import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core.types import CameraModel
from absscale_ros.sim import camera as simcam

F32 = npt.NDArray[np.float32]
FloatArray = npt.NDArray[np.float64]


class Rays:
    """Fixed per camera: rays through a set of pixel positions, structure of arrays."""

    def __init__(self, camera: CameraModel, pixels_px: FloatArray) -> None:
        xy = simcam.undistort_pixels(camera, pixels_px)
        self.x = xy[:, 0].astype(np.float32)  # undistorted normalised coordinates
        self.y = xy[:, 1].astype(np.float32)
        norm = np.sqrt(xy[:, 0] ** 2 + xy[:, 1] ** 2 + 1.0)
        self.dirs = (np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
                     / norm[:, None]).astype(np.float32)  # (N, 3) unit, camera frame
        self.dz = (1.0 / norm).astype(np.float32)  # z of the unit direction
        self.norm_cubed = (norm ** 3).astype(np.float32)


def rotate(vectors: F32, R: FloatArray) -> F32:
    """``vectors @ R.T`` for (N, 3) float32 arrays, by OpenCV (BLAS threads spin and starve)."""
    out = cv2.transform(np.ascontiguousarray(vectors, np.float32).reshape(-1, 1, 3),
                        np.asarray(R, np.float32))
    return out.reshape(-1, 3)


def dot(vectors: F32, v: FloatArray) -> F32:
    """``vectors @ v`` for (N, 3) arrays without BLAS."""
    vf = np.asarray(v, np.float32)
    return vectors[:, 0] * vf[0] + vectors[:, 1] * vf[1] + vectors[:, 2] * vf[2]
