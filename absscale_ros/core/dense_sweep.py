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
undistorted to a pinhole camera first (homographies hold only there). A window whose texture
varies only across every view's epipolar line (a straight edge along it: a floor's grout, a
cabinet's planks, an outline) matches equally well all along the line, so ``min_aperture``
drops it.
"""
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core import dense_stereo, lines
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
    min_aperture: float = 0.0  # windows with less of their gradient energy along an epipolar
    # line (in the view with most) than this share: dropped (a match sliding along an edge)
    edge_jump: float = 0.0  # depth jumps between neighbouring pixels above this fraction ...
    edge_radius_px: int = 3  # ... drop the pixels this close (window spill; 0 jump: keep)
    plane: bool = True  # also sweep planes parallel to the nearby points' dominant plane
    plane_band: float = 0.1  # ... offsets within this fraction of the plane's own
    plane_tolerance: float = 0.01  # RANSAC inlier distance, fraction of the points' range
    plane_trials: int = 100  # RANSAC samples
    plane_min_share: float = 0.2  # fewer points on the best plane: no slanted sweep
    plane_min_slant_deg: float = 20.0  # a plane facing the camera closer than this: none
    threads: int = 2  # planes swept on this many threads at once (the same depth)

    def __post_init__(self) -> None:
        if not 0.0 < self.scale <= 1.0 or self.views < 1 or self.window_px < 3 or \
                self.window_px % 2 == 0 or self.plane_step_px <= 0.0 or self.max_planes < 8 \
                or self.threads < 1:
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


def local_stats(img: Image32, win: tuple[int, int]) -> tuple[Image32, Image32]:
    """Mean and standard deviation of ``img`` over a ``win`` box around each pixel (ZNCC)."""
    mu = cv2.boxFilter(img, -1, win)
    sd = np.sqrt(np.maximum(cv2.boxFilter(img * img, -1, win) - mu * mu, 0.0))
    return mu, sd


def sweep(ref: Image32, others: list[tuple[Image32, FloatArray]], K: FloatArray,
          near_m: float, far_m: float, cfg: SweepConfig,
          plane: tuple[FloatArray, float] | None = None) -> Image32:
    """
    Depth of ``ref`` by a plane sweep over ``others``.

    :param others: (grey image, T_other_ref 4x4: reference camera points into the other's).
    :param near_m: nearest and farthest depth swept, m (z in the reference camera).
    :param plane: (unit normal n, offset d > 0) of a dominant plane ``n . X = d`` in the
        reference camera (``dominant_plane``): planes parallel to it are swept too, around
        it, and each pixel keeps whichever family matches it better. A fronto-parallel window
        on a surface seen at a grazing angle (the ground ahead) spans many depths and
        matches poorly; the same window slanted with the surface does not.
    :returns: (h, w) z in the reference camera, m; 0 where no depth is trusted.
    """
    h, w = ref.shape
    win = (cfg.window_px, cfg.window_px)
    mu_r, sd_r = local_stats(ref, win)
    stats = (mu_r, sd_r + np.float32(1e-2))
    K_inv = np.linalg.inv(K)
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    widest = max(float(np.linalg.norm(T[:3, 3])) for _, T in others)
    # Fronto-parallel planes z = d spaced in inverse depth (n . ray = 1 for every pixel).
    front = np.array([0.0, 0.0, 1.0])
    count = (1.0 / near_m - 1.0 / far_m) * K[0, 0] * widest / cfg.plane_step_px
    inv = np.linspace(1.0 / near_m, 1.0 / far_m, int(np.clip(np.ceil(count), 8, cfg.max_planes)))
    cost, inv_depth = _family(ref, stats, others, K, K_inv, front, inv, cfg)
    if plane is not None:
        n, d = plane
        # n . ray for each pixel (ray with z = 1): 1 / z = (n . ray) / d on a plane n . X = d.
        along = (n[0] * (u - K[0, 2]) / K[0, 0] + n[1] * (v - K[1, 2]) / K[1, 1] + n[2])
        shift = K[0, 0] * widest * max(float(np.percentile(along, 99)), 1e-3)
        lo, hi = 1.0 / (d * (1.0 + cfg.plane_band)), 1.0 / (d * (1.0 - cfg.plane_band))
        count = (hi - lo) * shift / cfg.plane_step_px
        offsets = np.linspace(hi, lo, int(np.clip(np.ceil(count), 8, cfg.max_planes)))
        cost_p, inv_p = _family(ref, stats, others, K, K_inv, n, offsets, cfg)
        inv_p *= along.astype(np.float32)
        better = (cost_p < cost) & (inv_p > 0)
        cost, inv_depth = np.where(better, cost_p, cost), np.where(better, inv_p, inv_depth)
    ok = (cost <= 1.0 - cfg.min_ncc) & (sd_r >= cfg.min_texture) & (inv_depth > 0)
    if cfg.min_aperture > 0.0:
        ok &= along_epipolar(ref, K, [T for _, T in others], win) >= cfg.min_aperture
    return np.where(ok, 1.0 / np.maximum(inv_depth, 1e-9), 0.0).astype(np.float32)


def along_epipolar(ref: Image32, K: FloatArray, poses: list[FloatArray],
                   win: tuple[int, int]) -> Image32:
    """
    The share of each window's gradient energy that lies along an epipolar line, in the view
    where it is largest: 0 on a straight edge that runs along every view's epipolar line (the
    aperture problem: its match slides along the edge), 1 where the texture varies only along
    one. ``poses`` are T_other_ref.
    """
    h, w = ref.shape
    gx = cv2.Sobel(ref, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(ref, cv2.CV_32F, 0, 1, ksize=3)
    sxx, syy = cv2.boxFilter(gx * gx, -1, win), cv2.boxFilter(gy * gy, -1, win)
    sxy = cv2.boxFilter(gx * gy, -1, win)
    u, v = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    best = np.zeros((h, w), np.float32)
    for T in poses:
        e = (K @ (-T[:3, :3].T @ T[:3, 3])).astype(np.float32)  # the other centre's image
        dx, dy = e[2] * u - e[0], e[2] * v - e[1]  # along the epipolar line through a pixel
        along = (dx * dx * sxx + 2.0 * dx * dy * sxy + dy * dy * syy) / \
            np.maximum(dx * dx + dy * dy, 1e-12)
        np.maximum(best, along, out=best)
    return best / np.maximum(sxx + syy, 1e-6)


def _family(ref: Image32, stats: tuple[Image32, Image32], others: list[tuple[Image32, FloatArray]],
            K: FloatArray, K_inv: FloatArray, normal: FloatArray, offsets: FloatArray,
            cfg: SweepConfig) -> tuple[Image32, Image32]:
    """
    Sweep of the planes ``normal . X = 1 / s`` for ``s`` in ``offsets`` (evenly spaced).

    The planes are split into ``cfg.threads`` runs swept at once (OpenCV and numpy let go of
    the GIL while they work on an image); each pixel's best plane of all runs is the first
    of the lowest costs, as one run finds it, so the result does not depend on the split.

    :returns: each pixel's best cost (inf where its best plane is the first or last: no
        minimum inside the range) and its sub-plane ``s``, refined by a parabola.
    """
    def cost(k: int) -> Image32:
        return _plane_cost(ref, stats, others, K, K_inv, normal * offsets[k], cfg)

    bounds = np.linspace(0, len(offsets), max(1, min(cfg.threads, len(offsets) // 8)) + 1)
    bounds = bounds.astype(int)
    runs = list(zip(bounds[:-1], bounds[1:]))
    if len(runs) == 1:
        parts = [_best_planes(cost, 0, len(offsets), len(offsets))]
    else:
        with ThreadPoolExecutor(len(runs)) as pool:
            parts = list(pool.map(lambda r: _best_planes(cost, r[0], r[1], len(offsets)), runs))
    best, index, left, right = parts[0]
    for b, i, lt, rt in parts[1:]:  # a later run's plane only when strictly better
        better = b < best
        for mine, theirs in ((best, b), (index, i), (left, lt), (right, rt)):
            np.copyto(mine, theirs, where=better)
    # Parabola through the best plane and its two neighbours (in plane-index units).
    curve = left - 2.0 * best + right
    ok = np.isfinite(curve) & (curve > 1e-6)
    offset = np.where(ok, 0.5 * (left - right) / np.where(ok, curve, 1.0), 0.0)
    refined = offsets[index] + np.clip(offset, -0.5, 0.5) * (offsets[1] - offsets[0])
    return np.where(ok, best, np.inf).astype(np.float32), refined.astype(np.float32)


def _best_planes(cost: Callable[[int], Image32], lo: int, hi: int,
                 count: int) -> tuple[Image32, npt.NDArray[np.int32], Image32, Image32]:
    """
    Each pixel's lowest cost among planes ``lo`` to ``hi - 1`` (the first, on a tie), its
    plane, and the costs of the planes either side of it (inf beyond the ``count`` planes):
    the planes ``lo - 1`` and ``hi`` are swept for those too.
    """
    first = cost(lo)
    best = np.full(first.shape, np.inf, np.float32)
    index = np.zeros(first.shape, np.int32)
    left, right = best.copy(), best.copy()
    previous = cost(lo - 1) if lo > 0 else best.copy()
    for k in range(lo, hi + 1 if hi < count else hi):
        current = first if k == lo else cost(k)
        np.copyto(right, current, where=index == k - 1)
        if k == hi:
            break
        better = current < best
        np.copyto(left, previous, where=better)
        np.copyto(right, np.inf, where=better)
        np.copyto(best, current, where=better)
        np.copyto(index, k, where=better)
        previous = current
    return best, index, left, right


def _plane_cost(ref: Image32, stats: tuple[Image32, Image32],
                others: list[tuple[Image32, FloatArray]], K: FloatArray, K_inv: FloatArray,
                plane: FloatArray, cfg: SweepConfig) -> Image32:
    """1 - the mean correlation (each at least ``1 - truncate``) of the neighbours warped
    into the reference through the plane ``plane . X = 1``."""
    h, w = ref.shape
    win = (cfg.window_px, cfg.window_px)
    mu_r, sd_r_eps = stats
    floor = np.float32(1.0 - cfg.truncate)  # a neighbour's correlation counts at least this
    score = np.zeros((h, w), np.float32)
    tmp = np.empty_like(score)
    for img, T in others:
        # x_other ~ K (R + t n^T / d) K^-1 x_ref for the plane n . X = d
        H = K @ (T[:3, :3] + np.outer(T[:3, 3], plane)) @ K_inv
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
    return np.subtract(1.0, score / len(others), out=score)


def dominant_plane(points: FloatArray, cfg: SweepConfig,
                   seed: int = 0) -> tuple[FloatArray, float] | None:
    """
    The plane most points of ``points`` (reference camera, m) lie on, by RANSAC, as (unit
    normal n, offset d > 0) with ``n . X = d``; None when too few points lie on any plane
    or when it already faces the camera (the fronto-parallel sweep covers it).
    """
    if len(points) < 50:
        return None
    rng = np.random.default_rng(seed)
    tolerance = cfg.plane_tolerance * np.median(np.linalg.norm(points, axis=1))
    best, best_in, best_count = None, np.zeros(len(points), bool), 0
    columns = np.ascontiguousarray(points.T)
    for a, b, c in rng.integers(0, len(points), (cfg.plane_trials, 3)):
        n = lines.cross3(points[b] - points[a], points[c] - points[a])
        if np.linalg.norm(n) < 1e-12:
            continue
        inside = np.abs(dense_stereo.plane_offsets(columns, points[a], n / np.linalg.norm(n))) \
            <= tolerance
        count = int(np.count_nonzero(inside))
        if count > best_count:
            best, best_in, best_count = n, inside, count
    if best is None or best_count < cfg.plane_min_share * len(points):
        return None
    inliers = points[best_in]
    centre = inliers.mean(0)  # least-squares refit on the inliers
    n = np.linalg.svd(inliers - centre, full_matrices=False)[2][2]
    d = float(n @ centre)
    n, d = (n, d) if d > 0 else (-n, -d)
    if d < 1e-6 or abs(n[2]) > np.cos(np.radians(cfg.plane_min_slant_deg)):
        return None
    return n, d


def depth_edges(depth: Image32, jump_rel: float, radius_px: int) -> npt.NDArray[np.bool_]:
    """
    Pixels within ``radius_px`` of a jump of more than ``jump_rel`` x depth between two
    neighbouring pixels with depth. A window straddling an object's outline matches the
    object: its depth spills onto the background there (points floating beside the object).
    """
    jump = np.zeros(depth.shape, bool)
    for a, b in ((depth[:, 1:], depth[:, :-1]), (depth[1:, :], depth[:-1, :])):
        step = (a > 0) & (b > 0) & (np.abs(a - b) > jump_rel * np.minimum(a, b))
        if a.shape[1] < depth.shape[1]:
            jump[:, 1:] |= step
            jump[:, :-1] |= step
        else:
            jump[1:, :] |= step
            jump[:-1, :] |= step
    size = 2 * radius_px + 1
    return cv2.dilate(jump.astype(np.uint8), np.ones((size, size), np.uint8)).astype(bool)


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
        along = dense_stereo.transform(unit, c[None, :])[..., 0]
        across = np.maximum(across, np.sqrt(np.maximum(c @ c - along * along, 0.0)))
    ok = depth * length <= max_baselines * across
    if max_step_m > 0.0:
        ok &= (depth * length) ** 2 <= max_step_m * K[0, 0] * across
    return ok
