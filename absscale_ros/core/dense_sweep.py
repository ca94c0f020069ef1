"""
Plane-sweep depth of one keyframe from several neighbouring keyframes (multi-view stereo).

A pair whose baseline runs along the optical axis (the camera walks towards what it scans)
cannot be rectified into usable rows, but a sweep needs no rectification: each neighbour is
warped into the reference view through the homography of a fronto-parallel plane, for planes
spaced evenly in inverse depth (a step moves a pixel about ``plane_step_px`` in the widest
neighbour), and each pixel takes the plane whose warps match it best. The match is the
zero-mean normalised cross-correlation over a window (no photometric calibration needed),
averaged over the better half of the neighbours so that one occluded view does not veto;
the best plane is refined by a parabola through its neighbours' costs. The images are
undistorted to a pinhole camera first (homographies hold only there).
"""
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core.types import CameraModel

FloatArray = npt.NDArray[np.float64]
Image32 = npt.NDArray[np.float32]


@dataclass(frozen=True)
class SweepConfig:
    """Plane sweep over neighbouring keyframes; pixel sizes at the sweep's scale."""

    enabled: bool = True  # sweep each keyframe (adds the views pairs cannot rectify)
    scale: float = 0.5  # sweep the working image resized by this factor (speed)
    views: int = 3  # neighbours warped into the reference (4: same figures, 10 % more CPU)
    span: int = 3  # keyframes on each side considered as neighbours
    lag: int = 1  # a keyframe is swept once this many later keyframes have poses
    window_px: int = 7  # correlation window, px
    plane_step_px: float = 1.0  # shift of a pixel between planes in the widest neighbour, px
    max_planes: int = 160  # planes at most (the step widens beyond)
    min_ncc: float = 0.7  # a depth whose matches correlate less (on average) is dropped
    truncate: float = 0.6  # one neighbour's cost (1 - correlation) counts at most this much
    min_texture: float = 2.0  # windows with a smaller grey-level deviation are dropped
    min_baseline_ratio: float = 0.02  # neighbours closer than this x depth: no parallax
    max_depth_baselines: float = 15.0  # deeper than this many baselines across the ray: dropped
    max_step_m: float = 0.0  # range change per pixel of parallax larger than this: dropped
    max_angle_deg: float = 40.0  # neighbours looking further away are not used, degrees

    def __post_init__(self) -> None:
        if not 0.0 < self.scale <= 1.0 or self.views < 1 or self.window_px < 3 or \
                self.window_px % 2 == 0 or self.plane_step_px <= 0.0 or self.max_planes < 8:
            raise ValueError(f'bad sweep config: {self}')


def pinhole_view(image_bgr: np.ndarray, camera: CameraModel,
                 cfg: SweepConfig) -> tuple[np.ndarray, Image32, FloatArray]:
    """
    The keyframe at the sweep's scale, undistorted to a pinhole camera of the same K.

    :returns: (h, w, 3) uint8 bgr, (h, w) float32 grey, (3, 3) K.
    """
    h, w = image_bgr.shape[:2]
    size = (max(16, int(round(w * cfg.scale))), max(16, int(round(h * cfg.scale))))
    small = image_bgr if size == (w, h) else cv2.resize(image_bgr, size,
                                                        interpolation=cv2.INTER_AREA)
    cam = camera.resized(*size)
    if cam.has_distortion:
        small = cv2.undistort(small, cam.K, cam.dist)
    grey = cv2.cvtColor(small, cv2.COLOR_BGR2GRAY).astype(np.float32)
    return small, grey, np.asarray(cam.K, np.float64)


def sweep(ref: Image32, others: list[tuple[Image32, FloatArray]], K: FloatArray,
          near_m: float, far_m: float, cfg: SweepConfig) -> Image32:
    """
    Depth of ``ref`` by a plane sweep over ``others``.

    :param others: (grey image, T_other_ref 4x4: reference camera points into the other's).
    :param near_m: nearest and farthest depth swept, m (z in the reference camera).
    :returns: (h, w) z in the reference camera, m; 0 where no depth is trusted.
    """
    h, w = ref.shape
    win = (cfg.window_px, cfg.window_px)
    mu_r = cv2.boxFilter(ref, -1, win)
    sd_r = np.sqrt(np.maximum(cv2.boxFilter(ref * ref, -1, win) - mu_r * mu_r, 0.0))
    sd_r_eps = sd_r + np.float32(1e-2)
    widest = max(float(np.linalg.norm(T[:3, 3])) for _, T in others)
    count = int(np.ceil((1.0 / near_m - 1.0 / far_m) * K[0, 0] * widest / cfg.plane_step_px))
    inv = np.linspace(1.0 / near_m, 1.0 / far_m, int(np.clip(count, 8, cfg.max_planes)))
    K_inv = np.linalg.inv(K)
    floor = np.float32(1.0 - cfg.truncate)  # a neighbour's correlation counts at least this
    best = np.full((h, w), np.inf, np.float32)
    index = np.zeros((h, w), np.int32)
    left, right, previous = best.copy(), best.copy(), best.copy()
    tmp, cost = np.empty_like(best), np.empty_like(best)
    for k, inv_d in enumerate(inv):
        score = np.zeros((h, w), np.float32)
        for img, T in others:
            # x_other ~ K (R + t n^T / d) K^-1 x_ref for the plane z = d, n = (0, 0, 1)
            H = K @ (T[:3, :3] + np.outer(T[:3, 3], [0.0, 0.0, inv_d])) @ K_inv
            warped = cv2.warpPerspective(img, H, (w, h), flags=cv2.INTER_LINEAR
                                         | cv2.WARP_INVERSE_MAP, borderValue=0.0)
            mu_w = cv2.boxFilter(warped, -1, win)
            var_w = cv2.boxFilter(np.multiply(warped, warped, out=tmp), -1, win)
            cross = cv2.boxFilter(np.multiply(ref, warped, out=tmp), -1, win)
            var_w -= np.multiply(mu_w, mu_w, out=tmp)
            np.sqrt(np.maximum(var_w, 1e-4, out=var_w), out=var_w)
            cross -= np.multiply(mu_r, mu_w, out=tmp)
            cross /= np.multiply(var_w, sd_r_eps, out=tmp)  # the correlation
            score += np.maximum(cross, floor, out=cross)
        np.subtract(1.0, score / len(others), out=cost)
        np.copyto(right, cost, where=index == k - 1)
        better = cost < best
        np.copyto(left, previous, where=better)
        np.copyto(right, np.inf, where=better)
        np.copyto(best, cost, where=better)
        np.copyto(index, k, where=better)
        previous, cost = cost, previous
    # Parabola through the best plane and its two neighbours (in plane-index units).
    curve = left - 2.0 * best + right
    ok = np.isfinite(curve) & (curve > 1e-6)
    offset = np.where(ok, 0.5 * (left - right) / np.where(ok, curve, 1.0), 0.0)
    inv_depth = inv[index] + np.clip(offset, -0.5, 0.5) * (inv[1] - inv[0])
    ok &= (best <= 1.0 - cfg.min_ncc) & (sd_r >= cfg.min_texture) & (inv_depth > 0)
    return np.where(ok, 1.0 / np.maximum(inv_depth, 1e-9), 0.0).astype(np.float32)


def precise(depth: Image32, K: FloatArray, centres: list[FloatArray], max_baselines: float,
            max_step_m: float = 0.0) -> npt.NDArray[np.bool_]:
    """
    Pixels whose range is at most ``max_baselines`` times the widest neighbour's baseline
    across their ray (near a neighbour's epipole its parallax vanishes), and whose range
    changes by at most ``max_step_m`` per pixel of parallax (range^2 / f B; 0: no limit).

    :param centres: the neighbours' camera centres in the reference camera, m.
    """
    h, w = depth.shape
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones((h, w))], -1)
    length = np.linalg.norm(rays, axis=-1)
    unit = rays / length[..., None]
    across = np.zeros((h, w))
    for c in centres:
        along = unit @ c
        across = np.maximum(across, np.sqrt(np.maximum(c @ c - along * along, 0.0)))
    ok = depth * length <= max_baselines * across
    if max_step_m > 0.0:
        ok &= (depth * length) ** 2 <= max_step_m * K[0, 0] * across
    return ok
