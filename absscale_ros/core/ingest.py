"""
Frame preparation for the front of the graph: resize to a maximum width and undistort.

Both happen in one ``cv2.remap`` whose maps are rebuilt whenever the input camera changes
(a resolution change mid-stream re-initialises, it does not crash). Also: reading a ROS
camera calibration YAML (``camera_calibration`` / ``camera_info_manager`` format) and counting
the frames a live stream lost from the gaps between stamps.
"""
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core import errors
from absscale_ros.core.types import CameraModel


@dataclass(frozen=True)
class IngestConfig:
    """
    :param max_width_px: frames wider than this are downscaled to it (0: never resize).
    :param undistort: remove lens distortion; the published camera_info then has none.
    :param undistort_alpha: 0 keeps only valid pixels (zoomed in), 1 keeps every source pixel.
    """

    max_width_px: int = 0
    undistort: bool = False
    undistort_alpha: float = 0.0

    def __post_init__(self) -> None:
        if self.max_width_px < 0 or (0 < self.max_width_px < 16):
            raise ValueError(f'max_width_px must be 0 or >= 16, got {self.max_width_px}')
        if not 0.0 <= self.undistort_alpha <= 1.0:
            raise ValueError(f'undistort_alpha must be in [0, 1], got {self.undistort_alpha}')


def output_size(width: int, height: int, max_width_px: int) -> tuple[int, int]:
    """Frame size after the optional downscale (aspect kept, height rounded)."""
    if max_width_px <= 0 or width <= max_width_px:
        return width, height
    return max_width_px, max(1, round(height * max_width_px / width))


class FramePreparer:
    """Turns frames of one input camera into frames of the output camera."""

    def __init__(self, cfg: IngestConfig) -> None:
        self.cfg = cfg
        self.camera_in: CameraModel | None = None
        self.camera_out: CameraModel | None = None
        self._maps: tuple[np.ndarray, np.ndarray] | None = None

    def configure(self, camera_in: CameraModel) -> bool:
        """Adopt ``camera_in``; return True when the output changed (re-initialised)."""
        same = self.camera_in is not None and _same(self.camera_in, camera_in)
        if same:
            return False
        w, h = output_size(camera_in.width, camera_in.height, self.cfg.max_width_px)
        self.camera_in = camera_in
        self._maps = None
        if self.cfg.undistort and camera_in.has_distortion:
            self.camera_out, self._maps = _undistort_maps(camera_in, w, h,
                                                          self.cfg.undistort_alpha)
        else:
            self.camera_out = camera_in.resized(w, h) if (w, h) != (camera_in.width,
                                                                    camera_in.height) \
                else camera_in
        return True

    def process(self, image: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]:
        """
        Resize and/or undistort one frame of the configured input camera.

        :param image: (H, W, 3) uint8 BGR of ``camera_in``'s size.
        :raises errors.MessageError: when the frame's size is not the camera's.
        """
        cin, cout = self.camera_in, self.camera_out
        if cin is None or cout is None:
            raise errors.NotObservableError('no camera model yet')
        h, w = image.shape[:2]
        if (w, h) != (cin.width, cin.height):
            raise errors.MessageError(f'frame is {w}x{h} but camera_info says '
                                      f'{cin.width}x{cin.height}')
        if self._maps is not None:
            return cv2.remap(image, self._maps[0], self._maps[1], cv2.INTER_LINEAR)
        if (cout.width, cout.height) != (w, h):
            return cv2.resize(image, (cout.width, cout.height), interpolation=cv2.INTER_AREA)
        return image


def _same(a: CameraModel, b: CameraModel) -> bool:
    return (a.width, a.height, a.distortion_model) == (b.width, b.height, b.distortion_model) \
        and np.array_equal(a.K, b.K) and np.array_equal(a.dist, b.dist)


def _undistort_maps(cam: CameraModel, width: int, height: int,
                    alpha: float) -> tuple[CameraModel, tuple[np.ndarray, np.ndarray]]:
    """Maps from the output (undistorted, resized) image into the input; the output model."""
    size_in = (cam.width, cam.height)
    if cam.distortion_model == 'equidistant':
        K_new = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(
            cam.K, cam.dist[:4], size_in, np.eye(3), balance=alpha)
    else:
        K_new, _ = cv2.getOptimalNewCameraMatrix(cam.K, cam.dist, size_in, alpha, size_in)
    out_full = CameraModel(cam.width, cam.height, K_new)
    out = out_full.resized(width, height) if (width, height) != size_in else out_full
    if cam.distortion_model == 'equidistant':
        m1, m2 = cv2.fisheye.initUndistortRectifyMap(cam.K, cam.dist[:4], np.eye(3), out.K,
                                                     (width, height), cv2.CV_16SC2)
    else:
        m1, m2 = cv2.initUndistortRectifyMap(cam.K, cam.dist, np.eye(3), out.K, (width, height),
                                             cv2.CV_16SC2)
    return out, (m1, m2)


class GapCounter:
    """
    Count frames missing from a stream from its stamps (a live stream's lost frames).

    The nominal period is the median of recent stamp steps; a step of ``k`` periods (rounded)
    means ``k - 1`` frames were lost on the way.
    """

    def __init__(self, window: int = 30) -> None:
        self._steps_ns: list[int] = []
        self._window = window
        self._last_ns: int | None = None
        self.missing = 0

    def add(self, stamp_ns: int) -> int:
        """Record a stamp; return how many frames are missing just before it."""
        last, self._last_ns = self._last_ns, stamp_ns
        if last is None or stamp_ns <= last:
            return 0
        step = stamp_ns - last
        lost = 0
        if len(self._steps_ns) >= 5:
            period = float(np.median(self._steps_ns))
            lost = max(0, int(round(step / period)) - 1)
        if lost == 0:
            self._steps_ns = (self._steps_ns + [step])[-self._window:]
        self.missing += lost
        return lost
