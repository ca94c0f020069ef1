"""
Depth of one keyframe from a second one: pair choice, rectification, semi-global matching.

The two views are rectified with their known (metric) relative pose, so that OpenCV's
StereoSGBM searches along image rows; its built-in left-right check (``disp12MaxDiff``) drops
occluded and ambiguous pixels. The disparity range comes from a few tracked corners of the
rectified pair (or matched ORB features where tracking fails), so neither the scene depth nor
the baseline has to be known beforehand.
Depth is kept in the *rectified* reference camera (its rotation ``R_rect`` and intrinsics
``K_rect`` go with it), which is where other keyframes' points are checked against it.
"""
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core.types import CameraModel

FloatArray = npt.NDArray[np.float64]
_MIN_RAY_DEG = 5.0  # rays closer to the baseline have too little parallax to be rectified
# OpenCV's SGBM modes. 'sgbm' and '3way' aggregate costs along paths that come from the rows
# above only, so on a surface whose disparity changes down the image (a floor, a desk) a plain
# stretch lags behind the rows above it: too deep with the partner on the right, too near on
# the left (the rectified image is upside down). 'hh4' adds the paths from below.
_MODES = {'sgbm': cv2.STEREO_SGBM_MODE_SGBM, '3way': cv2.STEREO_SGBM_MODE_SGBM_3WAY,
          'hh4': cv2.STEREO_SGBM_MODE_HH4, 'hh': cv2.STEREO_SGBM_MODE_HH}


@dataclass(frozen=True)
class StereoConfig:
    """Semi-global matching and pair selection; pixel sizes are at the working scale."""

    scale: float = 0.5  # work on keyframes resized by this factor (speed)
    target_baseline_ratio: float = 0.25  # preferred baseline / median depth of a pair
    max_forward_fraction: float = 0.5  # |baseline along the optical axis| / baseline above: no
    max_angle_deg: float = 30.0  # viewing directions further apart: no pair
    candidates: int = 6  # keyframes before and after tried as the second view
    block_size: int = 5  # SGBM matching window, px
    uniqueness: int = 10  # SGBM uniqueness margin, percent
    lr_max_diff: int = 1  # left-right disparity check tolerance, px
    speckle_window: int = 100  # connected blobs smaller than this are dropped, px
    speckle_range: int = 2  # disparity jump inside one blob, px
    max_disparities: int = 256  # widest disparity search, px
    min_disparity_px: float = 2.0  # smaller disparities (far, imprecise) are discarded
    max_depth_baselines: float = 15.0  # deeper than this many baselines: too imprecise, dropped
    max_step_m: float = 0.0  # depth change per pixel of disparity larger than this: dropped
    max_canvas_grow: float = 1.5  # rectified image at most this much larger than the keyframe
    widen_left: bool = True  # widen the canvas by SGBM's blind left margin (disparity range)
    min_texture: float = 0.0  # grey-level deviation in a block below this: no depth (0: keep)
    match_features: int = 800  # ORB features matched for the disparity range when tracking
    # fails (0: no fallback, range 0-96 px)
    mode: str = 'sgbm'  # SGBM's cost paths (``_MODES``): 'sgbm' comes only from above

    def __post_init__(self) -> None:
        if self.mode not in _MODES:
            raise ValueError(f'stereo mode {self.mode!r}: one of {", ".join(_MODES)}')


@dataclass
class DepthMap:
    """Depth of one reference keyframe in its rectified camera."""

    depth: npt.NDArray[np.float32]  # (H, W) z in the rectified camera, m; 0 = none
    colour: npt.NDArray[np.uint8]  # (H, W, 3) rectified reference image, bgr
    K_rect: FloatArray  # (3, 3) intrinsics of the rectified camera
    R_rect: FloatArray  # (3, 3) rotation from the keyframe's camera to the rectified one
    pair_stamp: int  # stamp of the second keyframe
    relative: FloatArray  # (4, 4) T_pair_ref the depth was computed with

    def points_camera(self, stride: int = 1) -> tuple[FloatArray, npt.NDArray[np.uint8]]:
        """Valid pixels (every ``stride``-th row and column) as (N, 3) points in the
        keyframe's (unrectified) camera, and colours."""
        rect, v, u = back_project(self.depth, self.K_rect, stride)
        return transform(rect, self.R_rect.T), self.colour[v, u]


def back_project(depth: npt.NDArray[np.floating], K: FloatArray, stride: int = 1
                 ) -> tuple[FloatArray, npt.NDArray[np.intp], npt.NDArray[np.intp]]:
    """The pixels of a depth image (z, m; 0 = none) with depth, every ``stride``-th row and
    column, as (N, 3) points in its pinhole camera ``K``, and their rows and columns."""
    v, u = np.nonzero(depth[::stride, ::stride] > 0)
    v, u = v * stride, u * stride
    z = depth[v, u].astype(np.float64)
    return np.stack([(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z], axis=1), v, u


def transform(points: FloatArray, A: FloatArray, b: FloatArray | None = None) -> FloatArray:
    """
    ``points @ A.T + b`` for (..., 3) points, column by column: numpy hands a product to
    its threaded BLAS, whose threads spin on a loaded machine (a 115k x 3 by 3 x 3 product
    took 31 ms of CPU at load 10 instead of 0.7 ms on one thread).
    """
    out = points[..., 0:1] * A[:, 0] + points[..., 1:2] * A[:, 1] + points[..., 2:3] * A[:, 2]
    if b is not None:
        out += b
    return out


def project(points: FloatArray, A: FloatArray, origin: FloatArray) -> FloatArray:
    """``(points - origin) @ A.T`` for (N, 3) points (``affine``)."""
    return affine(points, A, -(A @ origin))


def affine(points: FloatArray, A: FloatArray, b: FloatArray) -> FloatArray:
    """
    ``points @ A.T + b`` for (N, 3) points as one OpenCV pass (``cv2.transform``, on the
    calling thread when OpenCV's threads are off): the consistency check's inner loop, ~15
    times faster than ``transform`` on a shifted copy, equal to ~1e-15 relative (not to the
    bit: where a RANSAC counts inliers, ``transform`` keeps its bits).
    """
    M = np.empty((3, 4))
    M[:, :3], M[:, 3] = A, b
    return cv2.transform(np.ascontiguousarray(points).reshape(-1, 1, 3), M).reshape(-1, 3)


def plane_offsets(columns: FloatArray, origin: FloatArray, normal: FloatArray) -> FloatArray:
    """``(points - origin) . normal`` for points given as (3, N) rows of x, y and z, in the
    order ``transform`` sums them (the same bits, without an (N, 3) copy)."""
    out = (columns[0] - origin[0]) * normal[0]
    out += (columns[1] - origin[1]) * normal[1]
    out += (columns[2] - origin[2]) * normal[2]
    return out


def working_image(image: np.ndarray, camera: CameraModel,
                  cfg: StereoConfig) -> tuple[np.ndarray, CameraModel]:
    """The keyframe at the working scale, and its camera."""
    h, w = image.shape[:2]
    size = (int(round(w * cfg.scale)), int(round(h * cfg.scale)))
    if size == (w, h):
        return image, camera.resized(w, h)
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA), camera.resized(*size)


def relative_pose(T_world_a: FloatArray, T_world_b: FloatArray) -> FloatArray:
    """T_b_a: maps points of camera a into camera b."""
    return np.linalg.inv(T_world_b) @ T_world_a


def pair_quality(T_world_ref: FloatArray, T_world_other: FloatArray, depth_m: float,
                 cfg: StereoConfig) -> float | None:
    """How far a pair is from the preferred baseline ratio (lower is better); None if unusable."""
    T = relative_pose(T_world_other, T_world_ref)  # other camera in the reference frame
    c = T[:3, 3]
    baseline = float(np.linalg.norm(c))
    cos = np.clip((np.trace(T[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
    if baseline < 1e-9 or np.degrees(np.arccos(cos)) > cfg.max_angle_deg or \
            abs(c[2]) / baseline > cfg.max_forward_fraction:
        return None
    return abs(np.log(baseline / depth_m / cfg.target_baseline_ratio))


def _disparity_range(left: np.ndarray, right: np.ndarray, cfg: StereoConfig) -> tuple[int, int]:
    """
    (minDisparity, numDisparities) from corners tracked along the rectified rows, or, when
    fewer than 10 track (optical flow loses disparities beyond ~100 px: a near desk from a
    wide pair), from descriptor matches on the same rows.
    """
    corners = cv2.goodFeaturesToTrack(left, 400, 0.01, 8)
    lo, hi = 0.0, 64.0
    d = np.zeros(0)
    if corners is not None:
        moved, ok, _ = cv2.calcOpticalFlowPyrLK(left, right, corners, None, winSize=(21, 21),
                                                maxLevel=4)
        flow = (corners - moved).reshape(-1, 2)
        d = flow[(ok.ravel() == 1) & (np.abs(flow[:, 1]) < 1.5), 0]
    if len(d) < 10 and cfg.match_features > 0:
        d = _matched_disparities(left, right, cfg.match_features)
    if len(d) >= 10:
        lo, hi = np.percentile(d, [2, 98])
    lo = max(0, int(np.floor(lo * 0.8 - 4)))
    width = int(np.ceil((hi * 1.25 + 8 - lo) / 16.0)) * 16
    return lo, int(np.clip(width, 32, cfg.max_disparities))


def _matched_disparities(left: np.ndarray, right: np.ndarray, features: int) -> FloatArray:
    """Disparities of ORB matches (cross-checked) that lie on the same rectified row."""
    orb = cv2.ORB_create(features, fastThreshold=10)
    (k1, d1), (k2, d2) = (orb.detectAndCompute(g, None) for g in (left, right))
    if d1 is None or d2 is None:
        return np.zeros(0)
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(d1, d2)
    flow = np.array([np.subtract(k1[m.queryIdx].pt, k2[m.trainIdx].pt) for m in matches])
    return flow[np.abs(flow[:, 1]) < 1.5, 0] if len(flow) else np.zeros(0)


def rectifying_rotations(T_other_ref: FloatArray) -> tuple[FloatArray, FloatArray, float]:
    """
    Rotations of the reference and the other camera into a common rectified frame whose x
    axis points from the reference to the other camera (Fusiello et al. 2000), and the baseline.

    With the other camera on +x the reference is always the left image of the pair.
    """
    R, t = T_other_ref[:3, :3], T_other_ref[:3, 3]
    centre = -R.T @ t  # the other camera in the reference frame
    baseline = float(np.linalg.norm(centre))
    x = centre / baseline
    z_mean = np.array([0.0, 0.0, 1.0]) + R.T[:, 2]
    y = np.cross(z_mean, x)
    y /= np.linalg.norm(y)
    R_rect = np.stack([x, y, np.cross(x, y)])
    return R_rect, R_rect @ R.T, baseline


def _rectified_camera(K: FloatArray, R_rect: FloatArray, size: tuple[int, int],
                      max_grow: float) -> tuple[FloatArray, tuple[int, int]]:
    """
    Intrinsics and canvas (at most ``max_grow`` times the keyframe) of the rectified reference.

    A pair that moved mostly forward looks near its epipole, where rectification stretches
    the image without bound: the focal length shrinks as far as the canvas needs, at most by
    the typical stretch (so the view keeps its resolution), and rays stretched ``max_grow``
    times more than that (or within ``_MIN_RAY_DEG`` of the baseline: no parallax) are left
    out. A sideways pair keeps its focal length (precision).
    """
    w, h = size
    u, v = np.meshgrid(np.linspace(0, w - 1, 17), np.linspace(0, h - 1, 9))
    ray = np.linalg.inv(K) @ np.stack([u.ravel(), v.ravel(), np.ones(u.size)])
    ray /= np.linalg.norm(ray, axis=0)
    rect = R_rect @ ray
    usable = rect[2] > np.sin(np.radians(_MIN_RAY_DEG))
    stretch = (ray[2, usable] / rect[2, usable]) ** 1.5  # rectified / original pixel density
    typical = max(1.0, float(np.median(stretch)))
    keep = np.flatnonzero(usable)[stretch <= max_grow * typical]
    xy = rect[:2, keep] / rect[2, keep]  # at unit focal length
    # Shrink only as much as the canvas needs, and no more than the typical stretch.
    need = float(np.max((xy.max(1) - xy.min(1)) * K[0, 0] / (max_grow * np.array([w, h]))))
    f = float(K[0, 0]) / min(max(need, 1.0), typical)
    xy *= f
    lo, hi = xy.min(1), xy.max(1)
    span = np.minimum(hi - lo, np.array([w, h]) * max_grow)
    centre = np.clip(np.median(xy, axis=1), lo + span / 2, hi - span / 2)
    K_rect = np.array([[f, 0.0, span[0] / 2 - centre[0]], [0.0, f, span[1] / 2 - centre[1]],
                       [0.0, 0.0, 1.0]])
    return K_rect, (int(span[0]) + 1, int(span[1]) + 1)


def compute_depth(ref_bgr: np.ndarray, other_bgr: np.ndarray, camera: CameraModel,
                  T_world_ref: FloatArray, T_world_other: FloatArray, pair_stamp: int,
                  cfg: StereoConfig) -> DepthMap:
    """
    Depth of ``ref_bgr`` by semi-global matching against ``other_bgr``.

    :param camera: the camera of both images (their size, with its distortion); see
        ``working_image`` for the smaller copies the matching is meant to run on.
    """
    cam = camera
    size = (cam.width, cam.height)
    dist = cam.dist if cam.has_distortion else np.zeros(5)
    T = relative_pose(T_world_ref, T_world_other)  # ref -> other
    R_ref, R_other, baseline = rectifying_rotations(T)
    K_rect, canvas = _rectified_camera(cam.K, R_ref, size, cfg.max_canvas_grow)
    rect, inside = _rectify(ref_bgr, other_bgr, cam, dist, (R_ref, R_other), K_rect, canvas)
    grey = [cv2.cvtColor(r, cv2.COLOR_BGR2GRAY) for r in rect]
    lo, num = _disparity_range(grey[0], grey[1], cfg)
    # SGBM leaves the first lo + num columns without a disparity: widen both canvases to the
    # left by that much, so the whole reference is matched (the other image has more there).
    if cfg.widen_left:
        K_rect = K_rect.copy()
        K_rect[0, 2] += lo + num
        canvas = (canvas[0] + lo + num, canvas[1])
        rect, inside = _rectify(ref_bgr, other_bgr, cam, dist, (R_ref, R_other), K_rect, canvas)
        grey = [cv2.cvtColor(r, cv2.COLOR_BGR2GRAY) for r in rect]
    disp = _sgbm(grey[0], grey[1], lo, num, cfg)
    if cfg.min_texture > 0.0:  # a plain face: SGM's smoothness, not a match, sets its depth
        disp[_deviation(grey[0], cfg.block_size) < cfg.min_texture] = 0.0
    # A matching window that overlaps an image's black margin is biased: keep a block away.
    rim = np.ones((cfg.block_size, cfg.block_size), np.uint8)
    inside = [cv2.erode(m.astype(np.uint8), rim).astype(bool) for m in inside]
    disp[~inside[0]] = 0.0
    # The match must land inside the other image too (the black margin matches anything).
    v, u = np.nonzero(disp > 0)
    u2 = np.round(u - disp[v, u]).astype(int)
    ok = (u2 >= 0) & inside[1][v, np.clip(u2, 0, canvas[0] - 1)]
    disp[v[~ok], u[~ok]] = 0.0
    f = K_rect[0, 0]
    depth = np.where(disp >= cfg.min_disparity_px, f * baseline / np.maximum(disp, 1e-6), 0)
    depth[~_precise(depth, K_rect, baseline, cfg.max_depth_baselines)] = 0.0
    if cfg.max_step_m > 0.0:  # far points, however good relative to their depth (z^2 / f B)
        depth[depth * depth > cfg.max_step_m * f * baseline] = 0.0
    return DepthMap(depth.astype(np.float32), rect[0], K_rect, R_ref, pair_stamp, T)


def _deviation(grey: np.ndarray, size: int) -> np.ndarray:
    """Standard deviation of the grey levels in a ``size`` x ``size`` window round each pixel."""
    g = grey.astype(np.float32)
    mean = cv2.boxFilter(g, -1, (size, size))
    return np.sqrt(np.maximum(cv2.boxFilter(g * g, -1, (size, size)) - mean * mean, 0.0))


def _precise(depth: np.ndarray, K_rect: FloatArray, baseline: float,
             max_baselines: float) -> npt.NDArray[np.bool_]:
    """
    Pixels whose range is at most ``max_baselines`` times the baseline seen across their ray.

    Depth precision goes with the baseline perpendicular to the ray, B sin(phi), phi the angle
    between ray and baseline (the rectified x axis): a fixed cap on z would keep pixels near
    the epipole of a pair that moved forward, where the parallax vanishes.
    """
    h, w = depth.shape
    x = (np.arange(w) - K_rect[0, 2]) / K_rect[0, 0]
    y = (np.arange(h)[:, None] - K_rect[1, 2]) / K_rect[1, 1]
    across = np.sqrt(1.0 + y * y)  # |(y, z)| / z
    rng = np.sqrt(across * across + x * x)  # range / z
    # range <= N B sin(phi)  <=>  z range^2 <= N B |(y, z)|  (per unit z)
    return depth * rng * rng <= max_baselines * baseline * across


def _rectify(ref: np.ndarray, other: np.ndarray, cam: CameraModel, dist: FloatArray,
             rotations: tuple[FloatArray, FloatArray], K_rect: FloatArray,
             canvas: tuple[int, int]) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Both images rectified, and where each rectified pixel comes from inside its image."""
    rect, inside = [], []
    for img, R in zip((ref, other), rotations):
        mx, my = cv2.initUndistortRectifyMap(cam.K, dist, R, K_rect, canvas, cv2.CV_32FC1)
        rect.append(cv2.remap(img, mx, my, cv2.INTER_LINEAR))
        inside.append((mx >= 0) & (my >= 0) & (mx <= cam.width - 1) & (my <= cam.height - 1))
    return rect, inside


def _sgbm(left: np.ndarray, right: np.ndarray, lo: int, num: int,
          cfg: StereoConfig) -> np.ndarray:
    b = cfg.block_size
    if left.shape[1] <= lo + num + b:  # OpenCV refuses a canvas inside its blind margin
        return np.zeros(left.shape, np.float32)
    sgbm = cv2.StereoSGBM_create(
        minDisparity=lo, numDisparities=num, blockSize=b, P1=8 * b * b, P2=32 * b * b,
        disp12MaxDiff=cfg.lr_max_diff, uniquenessRatio=cfg.uniqueness,
        speckleWindowSize=cfg.speckle_window, speckleRange=cfg.speckle_range,
        mode=_MODES[cfg.mode])
    disp = sgbm.compute(left, right).astype(np.float32) / 16.0
    disp[disp < lo] = 0.0  # SGBM marks rejected pixels with minDisparity - 1
    return disp
