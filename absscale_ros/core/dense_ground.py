"""
Ground fill: the ground beyond the reach of stereo, on the plane the near ground lies on.

Outdoors the pairs and the sweep measure the ground to 8-12 m; beyond, seen at a grazing angle,
plain asphalt gives them nothing (outdoor 62 / 66 on true poses: asphalt 8-35 m away was 15 %
of the surface samples, a third of it found). But the near ground is measured by thousands of
points, and the plane they lie on is known to millimetres. So the ground farther on is filled
with that plane, where the image shows the ground: each candidate pixel (no depth of its own,
nothing measured in front of the plane there by the neighbours) is kept only where views a few
metres away, warped into the keyframe through the plane, agree with it (``dense_facade``'s
photometric check at full size: correlation where the window has texture, the grey level
where it is plain). A thing standing on the ground (a box, a bush, a façade) is not on the
plane, so the views warped through it do not agree there. Works in the keyframe's sweep view
(undistorted, at the sweep's scale).
"""
from dataclasses import dataclass, replace

import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core import dense_facade, dense_fill, dense_stereo

FloatArray = npt.NDArray[np.float64]
Mask = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class GroundConfig:
    """Which plane is the ground, how far it is filled and how each pixel is checked."""

    enabled: bool = False  # fill the ground beyond stereo with the near ground's plane
    lag: int = 3  # a keyframe is filled once this many later keyframes have poses
    stride: int = 4  # the plane fitted to every this-th pixel of the neighbours' depth maps
    max_range_m: float = 12.0  # ... nearer than this (the precise near ground), m
    plane_share: float = 0.3  # a plane holds at least this share of those points
    plane_trials: int = 100  # RANSAC samples
    plane_rel: float = 0.005  # points within this fraction of their depth lie on the plane
    min_slant_deg: float = 60.0  # the plane seen at least this far from its normal (ground
    # ahead, not a wall facing the camera), degrees
    far_m: float = 40.0  # filled up to this depth, m
    baseline_ratio: float = 0.1  # check views' preferred baseline / median candidate depth
    min_baseline_m: float = 1.0  # check views nearer than this: not used, m
    span: int = 6  # keyframes on each side considered as check views
    views: int = 3  # check views
    front_rel: float = 0.03  # a neighbour's point nearer than the plane by this fraction of
    # its depth marks the pixel as occupied (a thing standing on the ground)
    fill_ncc: float = 0.8  # textured pixel: warped views correlate at least this ...
    fill_texture: float = 4.0  # ... textured: grey-level deviation at least this (full size)
    fill_grey: float = 6.0  # plain pixel: mean grey level within this of each view's
    fill_views: int = 2  # views that must agree (none may contradict)
    window_px: int = 7  # correlation window of the check, px at full size
    enclosed_px: int = 48  # plain pixels only with agreeing texture within this above and
    # below, or left and right, px at full size (0: off)
    apart: bool = True  # its points cleaned apart from the keyframe's others, without the
    # statistical outlier removal (the far ground's rows are sparse, not outliers)

    def __post_init__(self) -> None:
        if self.lag < 0 or min(self.stride, self.plane_trials, self.span, self.views,
                               self.fill_views) < 1 or self.window_px < 3 or \
                self.far_m <= 0.0 or not 0.0 < self.plane_share <= 1.0:
            raise ValueError(f'bad ground config: {self}')


def ground_plane(points: FloatArray, cfg: GroundConfig) -> FloatArray | None:
    """
    The plane ``p`` (``p . X = 1``, camera frame) most of the near ``points`` lie on, when it
    is seen at a grazing angle (the ground ahead); None otherwise.
    """
    near = points[(points[:, 2] > 1e-6) & (np.linalg.norm(points, axis=1) < cfg.max_range_m)]
    if len(near) < 50:
        return None
    fit = dense_fill.FillConfig(max_planes=1, plane_share=cfg.plane_share,
                                plane_trials=cfg.plane_trials, plane_rel=cfg.plane_rel)
    planes = dense_fill.scene_planes(near, fit)
    if not planes:
        return None
    n, d = planes[0]
    if abs(n[2]) > np.cos(np.radians(cfg.min_slant_deg)):
        return None  # facing the camera: a wall, not the ground ahead
    return n / d


def check_views(poses: list[FloatArray], i: int, depth_m: float,
                cfg: GroundConfig) -> list[tuple[int, FloatArray]]:
    """Indices and T_view_kf of keyframe ``i``'s check views: baselines nearest
    ``baseline_ratio`` x ``depth_m``, at least ``min_baseline_m``."""
    target = max(cfg.baseline_ratio * depth_m, cfg.min_baseline_m)
    return dense_facade.views_near_baseline(poses, i, target, cfg.span, cfg.min_baseline_m,
                                            cfg.views)


def occupied(points: FloatArray, p: FloatArray, K: FloatArray, shape: tuple[int, ...],
             front_rel: float) -> Mask:
    """Pixels where a camera-frame point lies nearer than the plane ``p`` by more than
    ``front_rel`` of its depth (something stands on the ground there), dilated by a pixel."""
    h, w = shape
    z_plane = 1.0 / np.maximum(points @ p, 1e-9) * points[:, 2]  # plane z along each ray
    pts = points[(points[:, 2] > 1e-6) & (points[:, 2] < z_plane * (1.0 - front_rel))]
    hit = np.zeros((h, w), np.uint8)
    q = dense_stereo.transform(pts, K)
    u, v = np.rint(q[:, 0] / q[:, 2]).astype(np.intp), np.rint(q[:, 1] / q[:, 2]).astype(np.intp)
    ok = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    hit[v[ok], u[ok]] = 1
    return cv2.dilate(hit, np.ones((3, 3), np.uint8)) > 0


def candidates(p: FloatArray, K: FloatArray, blocked: Mask, cfg: GroundConfig) -> FloatArray:
    """The plane's z where a keyframe's ground may be filled (``blocked``: depth or
    something in front there), 0 elsewhere."""
    z = dense_facade.plane_depth(p, K, blocked.shape)
    return np.where(~blocked & (z > 0) & (z <= cfg.far_m), z, 0.0)


def fill(grey: np.ndarray, fine: dense_facade.Views, K: FloatArray, z: FloatArray,
         p: FloatArray, cfg: GroundConfig) -> FloatArray:
    """
    The ground plane's z on the candidate pixels of the sweep view (``grey``, ``K``; ``z``
    as ``candidates`` gives) where the check views (``fine``: full-size reference,
    (view, T_view_kf) list, K) warped through it agree; 0 elsewhere.
    """
    if not z.any():
        return np.zeros(grey.shape, np.float32)
    check = replace(dense_facade.FacadeConfig(), near_m=float(z[z > 0].min()),
                    far_m=float(z.max()) + 1e-6, window_px=cfg.window_px,
                    fill_ncc=cfg.fill_ncc, fill_texture=cfg.fill_texture,
                    fill_grey=cfg.fill_grey, fill_views=cfg.fill_views,
                    enclosed_px=cfg.enclosed_px, fill_plain=True)
    region = z > 0
    return dense_facade.facade_fill(grey, fine[1], K, ~region, [(p, region)], check, fine)
