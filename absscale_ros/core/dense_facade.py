"""
Far planes (façades) filled where photo-consistency does not contradict them.

Beyond the reach of the keyframe pairs and the near sweep (a building 35-60 m away is seen by
many keyframes, but with the near baselines its parallax is a pixel or two), a keyframe is
swept again over neighbours far apart (baselines a fraction of the far depth). Its per-pixel
far depths are too noisy to keep (plain plaster, repeating windows and bricks), but many of
them lie on a few planes: planes fitted to them by RANSAC average the noise away. Each plane
then gives a depth to every pixel of its region (near its inliers in the image) that no other
depth map of the keyframe covers, where the far views warped through the plane agree with
the keyframe: correlation where the window has texture, the mean grey level where it is plain
(a plain wall is what a surveyor would draw there). Fusion keeps those points only where
other keyframes' maps agree (multi-view support).
"""
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core import dense_stereo, dense_sweep
from absscale_ros.core.types import CameraModel

FloatArray = npt.NDArray[np.float64]
Image32 = npt.NDArray[np.float32]
Mask = npt.NDArray[np.bool_]
Views = tuple[Image32, list[tuple[Image32, FloatArray]], FloatArray]  # ref, (view, T), K


@dataclass(frozen=True)
class FacadeConfig:
    """
    Far sweep, plane fit and plane fill; pixel sizes at the sweep's scale, but the fill
    check's (``window_px`` there, ``enclosed_px``) at full size, where ``facade_fill`` is
    given the full-size views (``fine``, as ``DenseFusion`` always does).
    """

    enabled: bool = False  # off: no far planes
    near_m: float = 20.0  # far sweep from this depth ...
    far_m: float = 150.0  # ... to this one, m
    baseline_ratio: float = 0.25  # preferred far baseline / geometric mean of near_m and far_m
    min_baseline_m: float = 3.0  # far views closer than this: not used
    span: int = 12  # keyframes on each side considered as far views
    views: int = 3  # far views
    every: int = 1  # sweep every this many keyframes (the others borrow nothing)
    lag: int = 3  # a keyframe gets its far planes once this many later keyframes have poses
    window_px: int = 7  # correlation window of the far sweep and of the fill check, px
    min_ncc: float = 0.5  # far depths matched with a smaller correlation: not fitted
    min_texture: float = 2.0  # far depths in plainer windows: not fitted
    planes: int = 4  # planes fitted at most
    tolerance: float = 0.01  # RANSAC inlier distance, fraction of depth
    trials: int = 200  # RANSAC samples per plane
    ransac_sample: int = 0  # far depths a hypothesis is scored on at most (0: all)
    min_inliers: int = 200  # fewer far depths on a plane: not a plane
    max_slant_deg: float = 60.0  # planes seen further from their normal: not façades
    refine: bool = True  # planes aligned photometrically (Gauss-Newton) before the fill
    refine_stride: int = 3  # every this many of the plane's textured pixels drive the refinement
    fill_plain: bool = True  # plain pixels filled too (where the far views' grey levels agree)
    pool_deg: float = 3.0  # planes of other keyframes within this angle ...
    pool_m: float = 0.5  # ... and offset are the same façade, averaged with this one's
    hull_px: int = 2  # a plane's region: its inliers' pixels closed and dilated by this, px
    fill_ncc: float = 0.8  # a textured pixel's correlation through the plane at least this ...
    fill_texture: float = 4.0  # ... where its window's grey-level deviation is at least this
    fill_grey: float = 6.0  # a plain pixel's mean grey level within this of the far view's
    fill_views: int = 2  # far views that must agree (none may contradict)
    occluders: int = 0  # keyframes on each side whose points nearer than near_m mark pixels
    # as not façade (something in front; 0: the keyframe's own maps only)
    enclosed_px: int = 0  # a plain pixel only with agreeing texture within this both above and
    # below, or left and right, px at full size (the sky over a roof line is not; 0: off)

    def __post_init__(self) -> None:
        # (a negative ransac_sample would score on all but that many depths, a negative
        # occluders or enclosed_px would turn them off without a word)
        if not 0.0 < self.near_m < self.far_m or min(self.span, self.views, self.every,
                                                     self.trials, self.refine_stride,
                                                     self.fill_views) < 1 or \
                min(self.lag, self.planes, self.ransac_sample, self.occluders,
                    self.enclosed_px) < 0 or self.window_px < 3 or self.tolerance <= 0.0:
            raise ValueError(f'bad facade config: {self}')


def fine_view(image_bgr: np.ndarray, camera: CameraModel) -> tuple[np.ndarray, FloatArray]:
    """The full-size keyframe as undistorted uint8 grey, and its K (plane refinement)."""
    grey = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2GRAY)
    cam = camera.resized(grey.shape[1], grey.shape[0])
    if cam.has_distortion:
        grey = cv2.undistort(grey, cam.K, cam.dist)
    return grey, np.asarray(cam.K, np.float64)


def far_views(poses: list[FloatArray], i: int, cfg: FacadeConfig,
              max_angle_deg: float) -> list[tuple[int, FloatArray]]:
    """Indices and T_view_kf of keyframe ``i``'s far views (baseline nearest the target)."""
    return views_near_baseline(poses, i, cfg.baseline_ratio * np.sqrt(cfg.near_m * cfg.far_m),
                               cfg.span, cfg.min_baseline_m, cfg.views, max_angle_deg)


def views_near_baseline(poses: list[FloatArray], i: int, target_m: float, span: int,
                        min_baseline_m: float, views: int, max_angle_deg: float = 180.0
                        ) -> list[tuple[int, FloatArray]]:
    """Indices and T_view_kf of up to ``views`` keyframes within ``span`` of keyframe ``i``
    whose baselines come nearest ``target_m`` (by ratio), at least ``min_baseline_m``, turned
    at most ``max_angle_deg``."""
    scored = []
    for j in range(max(0, i - span), min(len(poses), i + span + 1)):
        T = dense_stereo.relative_pose(poses[i], poses[j])
        b = float(np.linalg.norm(T[:3, 3]))
        angle = np.degrees(np.arccos(np.clip((np.trace(T[:3, :3]) - 1) / 2, -1, 1)))
        if j != i and b >= min_baseline_m and angle <= max_angle_deg:
            scored.append((abs(np.log(b / target_m)), j, T))
    return [(j, T) for _, j, T in sorted(scored, key=lambda x: x[0])[:views]]


def plane_depth(p: FloatArray, K: FloatArray, shape: tuple[int, ...]) -> FloatArray:
    """(h, w) z of the plane ``p`` (``p . X = 1``, camera frame) on each pixel of a pinhole
    view, 0 where the ray misses it."""
    h, w = shape
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    along = p[0] * (u - K[0, 2]) / K[0, 0] + p[1] * (v - K[1, 2]) / K[1, 1] + p[2]
    return np.where(along > 1e-9, 1.0 / np.maximum(along, 1e-9), 0.0)


def fit_planes(points: FloatArray, cfg: FacadeConfig,
               seed: int = 0) -> list[tuple[FloatArray, float, npt.NDArray[np.bool_]]]:
    """Planes (n, d > 0 with n . X = d, inlier mask) on camera-frame points, by RANSAC."""
    rng = np.random.default_rng(seed)
    left = np.ones(len(points), bool)
    depth = np.maximum(points[:, 2], 1e-6)
    out = []
    for _ in range(cfg.planes):
        idx = np.flatnonzero(left)
        if len(idx) < cfg.min_inliers:
            break
        p = points[idx]
        tol = cfg.tolerance * depth[idx]
        # hypotheses scored on a sample (CPU), the winner's inliers taken from all points
        few = rng.permutation(len(p))[:cfg.ransac_sample] if cfg.ransac_sample else slice(None)
        q, q_tol = p[few], tol[few]
        best, best_n = None, 0
        for a, b, c in rng.integers(0, len(q), (cfg.trials, 3)):
            n = np.cross(q[b] - q[a], q[c] - q[a])
            norm = np.linalg.norm(n)
            if norm < 1e-9:
                continue
            n /= norm
            count = int(np.count_nonzero(np.abs(dense_stereo.transform(q - q[a], n[None])[:, 0])
                                         <= q_tol))
            if count > best_n:
                best, best_n = (q[a], n), count
        if best is None:
            break
        best = np.abs(dense_stereo.transform(p - best[0], best[1][None])[:, 0]) <= tol
        if best.sum() < cfg.min_inliers:
            break
        for _ in range(2):  # least-squares refit, inliers again
            q = p[best]
            centre = q.mean(0)
            n = np.linalg.svd(q - centre, full_matrices=False)[2][2]
            best = np.abs((p - centre) @ n) <= tol
        d = float(n @ centre)
        n, d = (n, d) if d > 0 else (-n, -d)
        mask = np.zeros(len(points), bool)
        mask[idx[best]] = True
        left &= ~mask
        if d > 1e-6:
            out.append((n, d, mask))
    return out


def refine_plane(grey: Image32, others: list[tuple[Image32, FloatArray]], K: FloatArray,
                 plane: FloatArray, pixels: npt.NDArray[np.intp], iterations: int = 8,
                 huber: float = 1.0) -> FloatArray:
    """
    The plane ``p = n / d`` (``p . X = 1``) that best aligns ``others`` warped into ``grey``
    over ``pixels`` ((N, 2) u, v), by Gauss-Newton on normalised grey levels: thousands of
    pixels pin a plane to a small fraction of a pixel of parallax where one pixel cannot.
    """
    u, v = pixels[:, 0].astype(np.float64), pixels[:, 1].astype(np.float64)
    y = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], 1)
    ref = grey[pixels[:, 1], pixels[:, 0]].astype(np.float64)
    ref = (ref - ref.mean()) / max(ref.std(), 1e-6)
    prepared = []
    for img, T in others:
        gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3) / 8.0
        gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3) / 8.0
        prepared.append((img, gx, gy, y @ (K @ T[:3, :3]).T, K @ T[:3, 3]))
    p = np.asarray(plane, np.float64).copy()
    for _ in range(iterations):
        JtJ, Jtr = np.zeros((3, 3)), np.zeros(3)
        for img, gx, gy, a, kt in prepared:
            xh = a + np.outer(y @ p, kt)
            w = xh[:, 2]
            ok = w > 1e-6
            uo, vo = xh[:, 0] / np.where(ok, w, 1.0), xh[:, 1] / np.where(ok, w, 1.0)
            h, wd = img.shape
            ok &= (uo >= 1) & (uo < wd - 2) & (vo >= 1) & (vo < h - 2)
            if ok.sum() < 50:
                continue
            mx, my = uo[ok].astype(np.float32), vo[ok].astype(np.float32)
            val, ix, iy = (_sample(m, mx, my) for m in (img, gx, gy))
            mean, sd = val.mean(), max(val.std(), 1e-6)
            # d(value)/d(xh), then along kt: d xh / d p = kt y^T
            wk = w[ok]
            dx = np.stack([ix / wk, iy / wk, -(ix * uo[ok] + iy * vo[ok]) / wk], 1)
            J = (dx @ kt)[:, None] * y[ok]
            J = (J - J.mean(0)) / sd
            r = (val - mean) / sd - ref[ok]
            weight = np.minimum(1.0, huber / np.maximum(np.abs(r), 1e-9))
            JtJ += (J * weight[:, None]).T @ J
            Jtr += (J * weight[:, None]).T @ r
        if not JtJ.any():
            break
        step = np.linalg.solve(JtJ + 1e-6 * np.trace(JtJ) * np.eye(3), -Jtr)
        p += step
        if np.linalg.norm(step) < 1e-6 * np.linalg.norm(p):
            break
    return p


def _sample(img: Image32, x: Image32, y: Image32, width: int = 4096) -> FloatArray:
    """Bilinear samples of ``img`` at (x, y), in rows of ``width`` (remap's maps must stay
    under 32767 pixels a side)."""
    pad = -len(x) % width
    mx, my = (np.concatenate([c, np.zeros(pad, np.float32)]).reshape(-1, width) for c in (x, y))
    return cv2.remap(img, mx, my, cv2.INTER_LINEAR).ravel()[:len(x)].astype(np.float64)


def facade_planes(grey: Image32, others: list[tuple[Image32, FloatArray]], K: FloatArray,
                  covered: npt.NDArray[np.bool_], cfg: FacadeConfig,
                  sweep_cfg: dense_sweep.SweepConfig,
                  fine: tuple[Image32, list[tuple[Image32, FloatArray]], FloatArray] | None = None
                  ) -> list[tuple[FloatArray, npt.NDArray[np.bool_], int]]:
    """
    Far planes of the reference ``grey`` where ``covered`` (other depth) is False.

    :param others: far views (grey image, T_view_ref).
    :param fine: the same images at a finer scale (and its K) for the plane refinement.
    :returns: (p = n / d with p . X = 1 in the reference camera, region mask, pixels
        that refined it) for each plane.
    """
    h, w = grey.shape
    far_cfg = dense_sweep.SweepConfig(scale=sweep_cfg.scale, window_px=cfg.window_px,
                                      plane_step_px=sweep_cfg.plane_step_px,
                                      max_planes=sweep_cfg.max_planes, min_ncc=cfg.min_ncc,
                                      truncate=sweep_cfg.truncate, min_texture=cfg.min_texture,
                                      plane=False)
    far = dense_sweep.sweep(grey, others, K, cfg.near_m, cfg.far_m, far_cfg)
    far[covered] = 0.0  # what nearer maps hold is not a far surface
    v, u = np.nonzero(far > 0)
    z = far[v, u].astype(np.float64)
    pts = np.stack([(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z], axis=1)
    out: list[tuple[FloatArray, npt.NDArray[np.bool_], int]] = []
    if len(pts) < cfg.min_inliers:
        return out
    win = (cfg.window_px, cfg.window_px)
    size = 2 * cfg.hull_px + 1
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
    g, o, Kf = fine if fine is not None else (grey, others, K)
    textured = dense_sweep.local_stats(g, win)[1] >= cfg.fill_texture
    for n, d, mask in fit_planes(pts, cfg):
        ray = np.median(pts[mask], axis=0)
        if n @ ray / np.linalg.norm(ray) < np.cos(np.radians(cfg.max_slant_deg)):
            continue  # seen too obliquely (the ground far ahead): not a façade
        inl = np.zeros((h, w), np.uint8)
        inl[v[mask], u[mask]] = 1
        region = cv2.dilate(cv2.morphologyEx(inl, cv2.MORPH_CLOSE, kernel), kernel) > 0
        p, used = n / d, 0
        if cfg.refine:
            inl = cv2.dilate(inl, np.ones((3, 3), np.uint8))
            if fine is not None:
                inl = cv2.resize(inl, g.shape[::-1], interpolation=cv2.INTER_NEAREST)
            fit = np.argwhere((inl > 0) & textured)[:, ::-1][::cfg.refine_stride]
            if len(fit) >= cfg.min_inliers:
                q = refine_plane(g, o, Kf, p, fit)
                if q @ ray > 0:
                    p, used = q, len(fit)
        out.append((p, region, used))
    return out


def facade_fill(grey: Image32, others: list[tuple[Image32, FloatArray]], K: FloatArray,
                covered: Mask, planes: list[tuple[FloatArray, Mask]], cfg: FacadeConfig,
                fine: Views | None = None
                ) -> Image32:
    """
    Depth from ``planes`` ((p, region mask) as ``facade_planes`` gives) where ``covered`` is
    False and the far views warped through the plane agree with ``grey``.

    :returns: (h, w) z, m; 0 where no plane is kept.
    """
    h, w = grey.shape
    out = np.zeros((h, w), np.float32)
    for p, region in planes:
        zp = plane_depth(p, K, (h, w))
        cand = region & ~covered & (out == 0) & (zp >= cfg.near_m) & (zp <= cfg.far_m)
        if not cand.any():
            continue
        keep = cand & _consistent(grey, others, K, p, cfg, _box(cand, (h, w), cfg.window_px)) \
            if fine is None else cand & _coarse(_consistent(
                *fine, p, cfg, _box(cand, fine[0].shape, cfg.window_px)), (w, h))
        out[keep] = zp[keep]
    return out


def _box(mask: Mask, shape: tuple[int, ...], margin: int) -> tuple[int, int, int, int]:
    """Bounding box (x0, y0, x1, y1) of ``mask`` in an image of ``shape`` (h, w), the same
    view at a larger size (zoom: the ratio of widths), widened by ``margin`` px and clipped to
    that image. (Its height need not be the zoomed mask's: both sizes are rounded.)"""
    v, u = np.nonzero(mask)
    h, w = shape[:2]
    zoom = w / mask.shape[1]
    return (max(0, int(u.min() * zoom) - margin), max(0, int(v.min() * zoom) - margin),
            min(w, int((u.max() + 1) * zoom) + margin), min(h, int((v.max() + 1) * zoom) + margin))


def _coarse(mask: npt.NDArray[np.bool_], size: tuple[int, int]) -> npt.NDArray[np.bool_]:
    """A fine mask at a coarser size: where most of a coarse pixel's fine pixels are set."""
    return cv2.resize(mask.astype(np.float32), size, interpolation=cv2.INTER_AREA) >= 0.5


def _consistent(grey: Image32, others: list[tuple[Image32, FloatArray]], K: FloatArray,
                p: FloatArray, cfg: FacadeConfig,
                box: tuple[int, int, int, int] | None = None) -> npt.NDArray[np.bool_]:
    """
    Pixels where the views warped through plane ``p`` agree with ``grey``, inside ``box``
    (x0, y0, x1, y1; the rest False): only the candidates' box is warped.
    """
    h, w = grey.shape
    x0, y0, x1, y1 = box or (0, 0, w, h)
    ref = grey[y0:y1, x0:x1]
    win = (cfg.window_px, cfg.window_px)
    mu_r, sd_r = dense_sweep.local_stats(ref, win)
    shift = np.array([[1.0, 0.0, x0], [0.0, 1.0, y0], [0.0, 0.0, 1.0]])
    K_inv = np.linalg.inv(K)
    agree = np.zeros(ref.shape, np.int32)
    against = np.zeros(ref.shape, bool)
    textured = sd_r >= cfg.fill_texture
    for img, T in others:
        H = K @ (T[:3, :3] + np.outer(T[:3, 3], p)) @ K_inv @ shift
        warped = cv2.warpPerspective(img, H, (x1 - x0, y1 - y0), flags=cv2.INTER_LINEAR
                                     | cv2.WARP_INVERSE_MAP, borderValue=-1.0)
        inside = cv2.erode((warped >= 0).astype(np.uint8), np.ones(win, np.uint8)) > 0
        mu_w, sd_w = dense_sweep.local_stats(warped, win)
        ncc = (cv2.boxFilter(ref * warped, -1, win) - mu_r * mu_w) / \
            np.maximum(sd_r * sd_w, 1e-3)
        ok_t = textured & (ncc >= cfg.fill_ncc)
        ok_p = cfg.fill_plain & ~textured & (sd_w < cfg.fill_texture) & \
            (np.abs(mu_r - mu_w) <= cfg.fill_grey)
        ok = inside & (ok_t | ok_p)
        agree += ok
        against |= inside & ~ok
    keep = (agree >= cfg.fill_views) & ~against
    if cfg.fill_plain and cfg.enclosed_px > 0:  # plain only between textured agreement
        keep &= textured | _enclosed(keep & textured, cfg.enclosed_px)
    out = np.zeros((h, w), bool)
    out[y0:y1, x0:x1] = keep
    return out


def _enclosed(mask: Mask, reach: int) -> Mask:
    """Pixels with ``mask`` within ``reach`` px both above and below, or both left and
    right: a plain wall between windows, not the sky over a roof line."""
    m = mask.astype(np.uint8)
    col, row = np.ones((reach, 1), np.uint8), np.ones((1, reach), np.uint8)
    above = cv2.dilate(m, col, anchor=(0, reach - 1))
    below = cv2.dilate(m, col, anchor=(0, 0))
    left = cv2.dilate(m, row, anchor=(reach - 1, 0))
    right = cv2.dilate(m, row, anchor=(0, 0))
    return ((above & below) | (left & right)) > 0


def pooled(p: FloatArray, T_world_cam: FloatArray,
           known: list[tuple[FloatArray, int]], cfg: FacadeConfig) -> FloatArray:
    """
    Plane ``p`` (camera frame) averaged with the same façade's planes found from other
    keyframes (``known``: world-frame (n, d) as 4-vectors, refinement pixels): each is pinned
    to a few centimetres, their mean to less.
    """
    n, d = p / np.linalg.norm(p), 1.0 / np.linalg.norm(p)
    R, c = T_world_cam[:3, :3], T_world_cam[:3, 3]
    nw = R @ n
    dw = d + nw @ c
    total, weight = np.zeros(4), 0.0
    for q, count in known:
        if q[:3] @ nw >= np.cos(np.radians(cfg.pool_deg)) and abs(q[3] - dw) <= cfg.pool_m:
            total += count * q
            weight += count
    if weight == 0:
        return p
    nw, dw = total[:3] / np.linalg.norm(total[:3]), total[3] / np.linalg.norm(total[:3])
    n, d = R.T @ nw, dw - nw @ c
    return n / d


def world_plane(p: FloatArray, T_world_cam: FloatArray) -> FloatArray:
    """Camera-frame ``p`` as a world-frame (n, d) 4-vector."""
    n, d = p / np.linalg.norm(p), 1.0 / np.linalg.norm(p)
    nw = T_world_cam[:3, :3] @ n
    return np.concatenate([nw, [d + nw @ T_world_cam[:3, 3]]])
