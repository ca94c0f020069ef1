"""
Plane fill of plain holes: a hole in a keyframe's depth filled with the plane around it.

A plain wall (paint, plaster) or a blank sheet gives stereo nothing to match, so a keyframe's
depth has holes wherever the surface is plain (indoors, plain walls are 41-55 % of the
surface and stereo found half of them), while around them texture, edges and the things on
the wall do match. The candidates are the largest planes of the keyframe's neighbourhood
(walls, floor, desk top: fitted to many views' points, they do not tilt with the few points
around one hole). A hole (plain pixels without depth, cut apart by image edges) takes the
plane that most of its rim points lie on, provided that few rim points lie behind it (it is
the backdrop: points off it are things standing before it) and that those on it lie around
the hole, not along one side (a desk top meets the wall along its back edge only). Its pixels
get the plane's depth where that stays within the depths of the plane's rim points and, when
``rim_hull`` is set, near them: a plane known from one patch of a wall tilts, and the error
grows with the distance from that patch (indoor 77's far wall: -6 to +6 cm across the view).
A large hole (``inside_px``) takes only a plane some view measured inside it: a plain wall no
view measured has only the outlines of the things before it on its rim, and their spill (an
outline's depth given to the plain pixels beside it), through which a plane fits off the wall.
Works in the keyframe's sweep view (undistorted, at the sweep's scale).
"""
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core import dense_stereo, lines

FloatArray = npt.NDArray[np.float64]
Mask = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class FillConfig:
    """Which holes are filled with which planes; pixel sizes at the sweep's scale."""

    enabled: bool = False  # fill plain holes with the plane around them
    lag: int = 3  # a keyframe is filled once this many later keyframes have poses
    stride: int = 8  # planes fitted to every this-th pixel of the neighbourhood's depth maps
    max_planes: int = 6  # planes looked for in a keyframe's neighbourhood at most
    plane_share: float = 0.05  # a plane holds at least this share of those points
    plane_trials: int = 60  # RANSAC samples per plane
    plane_rel: float = 0.005  # points within this fraction of their depth lie on a plane
    plane_refit: float = 0.5  # the plane refitted to its points within this x that distance
    plain_sd: float = 2.0  # grey-level deviation in a window below this: plain (fillable)
    window_px: int = 7  # ... over this window, px
    min_px: int = 30  # smaller holes are left (the voxels bridge them anyway)
    max_holes: int = 40  # largest holes tried per keyframe at most (CPU)
    rim_px: int = 5  # the rim: measured pixels this close around a hole
    min_rim: int = 40  # fewer rim points: no plane trusted
    min_share: float = 0.2  # fewer of the rim points on the plane: not its plane
    max_behind: float = 0.05  # more rim points behind the plane: not its plane (not a backdrop)
    behind_rel: float = 0.02  # ... behind: farther than the plane by this fraction of depth
    enclosed: float = 0.5  # share of a hole's outline the measured rim must touch
    min_spread: float = 0.3  # the plane's rim points spread across the hole at least this x
    # its own spread, along its narrowest direction (not only along one side of it)
    border_open: bool = True  # a hole's stretch along the image border counts against it
    band: float = 0.1  # filled depths beyond the plane's rim points' by more than this
    # fraction: left empty
    rim_hull: float = -1.0  # filled only within the hull of the plane's rim points, grown by
    # this x its radius (a tilt's error grows with the distance from them; negative: off)
    max_slant_deg: float = 80.0  # a plane seen more obliquely (its depth runs away): no fill
    inside_px: int = 0  # a hole whose core (its pixels window_px // 2 + 1 px from its
    # outline) is at least this large takes only a plane some of the neighbourhood's points
    # on it fall into (0: no test)

    def __post_init__(self) -> None:
        if self.min_px < 1 or self.rim_px < 1 or self.min_rim < 3 or self.stride < 1 or \
                not 0.0 < self.min_share <= 1.0 or not 0.0 <= self.enclosed <= 1.0 or \
                self.window_px < 3 or self.plane_trials < 1 or self.lag < 0 or \
                self.max_planes < 1 or self.max_holes < 1:
            raise ValueError(f'bad fill config: {self}')


def depth_image(points_cam: FloatArray, K: FloatArray, shape: tuple[int, ...]) -> FloatArray:
    """The nearest camera-frame point's z on each pixel of a pinhole view (0: none)."""
    h, w = shape
    depth = np.zeros((h, w))
    p = dense_stereo.transform(points_cam, K)
    p = p[p[:, 2] > 1e-6]
    u = np.rint(p[:, 0] / p[:, 2]).astype(np.intp)
    v = np.rint(p[:, 1] / p[:, 2]).astype(np.intp)
    ok = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    order = np.argsort(-p[ok, 2])  # farthest first: the nearest is written last
    depth[v[ok][order], u[ok][order]] = p[ok, 2][order]
    return depth


def scene_planes(points: FloatArray, cfg: FillConfig,
                 seed: int = 0) -> list[tuple[FloatArray, float]]:
    """
    The largest planes (n, d: n . X = d > 0) of a keyframe's neighbourhood (camera-frame
    points), one after the other by RANSAC: walls, floor, desk top. Fitted to many views'
    points, such a plane does not tilt with the few points around one hole.
    """
    rng = np.random.default_rng(seed)
    planes: list[tuple[FloatArray, float]] = []
    left = points
    while len(planes) < cfg.max_planes and len(left) >= 3:
        tol = cfg.plane_rel * np.abs(left[:, 2])
        best, best_count = np.zeros(len(left), bool), 0
        columns = np.ascontiguousarray(left.T)  # x, y, z rows: each trial reads them whole
        for a, b, c in rng.integers(0, len(left), (cfg.plane_trials, 3)):
            n = lines.cross3(left[b] - left[a], left[c] - left[a])
            norm = np.linalg.norm(n)
            if norm < 1e-12:
                continue
            inside = np.abs(dense_stereo.plane_offsets(columns, left[a], n / norm)) <= tol
            count = int(np.count_nonzero(inside))
            if count > best_count:
                best, best_count = inside, count
        if best_count < max(3, cfg.plane_share * len(points)):
            break
        n, d = _refit(left, best, cfg.plane_refit * tol)
        planes.append((n, d))
        left = left[~best]
    return planes


def _refit(points: FloatArray, inliers: Mask, tol: FloatArray) -> tuple[FloatArray, float]:
    """Least squares on the inliers, then again on those within ``tol`` of that plane (the
    plane's own points, without a neighbouring surface's or a spill's)."""
    for _ in range(2):
        centre = points[inliers].mean(0)
        n = np.linalg.svd(points[inliers] - centre, full_matrices=False)[2][2]
        d = float(n @ centre)
        n, d = (n, d) if d > 0 else (-n, -d)
        tighter = inliers & (np.abs(dense_stereo.transform(points, n[None, :])[:, 0] - d) <= tol)
        if tighter.sum() < 3:
            break
        inliers = tighter
    return n, d


def fill(measured: FloatArray, grey: np.ndarray, K: FloatArray,
         planes: list[tuple[FloatArray, float]], cfg: FillConfig,
         nearby: FloatArray | None = None) -> FloatArray:
    """
    Depth for the plain holes of a keyframe's depth.

    :param measured: (h, w) the keyframe's depth in its sweep view (``depth_image``), m, 0
        where none; ``grey`` that view's float grey, ``K`` its intrinsics.
    :param planes: candidate planes in its camera (``scene_planes``).
    :param nearby: the points the planes were fitted to (camera frame), for ``inside_px``.
    :returns: (h, w) z on the filled holes' planes, m; 0 elsewhere.
    """
    h, w = grey.shape
    covered = cv2.dilate((measured > 0).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    win = (cfg.window_px, cfg.window_px)
    mu = cv2.boxFilter(grey, -1, win)
    sd = np.sqrt(np.maximum(cv2.boxFilter(grey * grey, -1, win) - mu * mu, 0.0))
    holes = (~covered & (sd < cfg.plain_sd)).astype(np.uint8)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(holes, 4)
    areas = stats[1:, cv2.CC_STAT_AREA]
    order = [1 + k for k in np.argsort(-areas) if areas[k] >= cfg.min_px][:cfg.max_holes]
    rays = _rays(K, h, w)
    seen = _seen_on_planes(nearby, K, (h, w), planes, cfg) \
        if cfg.inside_px > 0 and nearby is not None else None
    out = np.zeros((h, w), np.float32)
    for label in order if planes else []:
        box = _box(stats[label], cfg.rim_px + 1, h, w)
        hole = labels[box] == label
        usable = planes if seen is None else _seen_inside(hole, seen[:, box[0], box[1]],
                                                          planes, cfg)
        z = _hole_depth(hole, measured[box], rays[box], (box, h, w), usable, cfg) \
            if usable else None
        if z is not None:
            out[box][hole] = z
    return out


def _seen_on_planes(points: FloatArray, K: FloatArray, shape: tuple[int, int],
                    planes: list[tuple[FloatArray, float]],
                    cfg: FillConfig) -> Mask:
    """(planes, h, w): the pixels some of the neighbourhood's points on each plane fall on.
    A plain wall no view measured leaves its plane's pixels empty there: the rim points of
    its holes are then the outlines of things before it and their spill (an outline's depth
    given to the plain pixels beside it), through which a plane fits off the wall (indoor
    65, with ``sweep.min_aperture``: 4-5 cm too near)."""
    h, w = shape
    seen = np.zeros((len(planes), h, w), bool)
    p = dense_stereo.transform(points, K)
    front = p[:, 2] > 1e-6
    p, points = p[front], points[front]
    u = np.rint(p[:, 0] / p[:, 2]).astype(np.intp)
    v = np.rint(p[:, 1] / p[:, 2]).astype(np.intp)
    ok = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    u, v, points = u[ok], v[ok], points[ok]
    for k, (n, d) in enumerate(planes):
        on = np.abs(points @ n - d) <= cfg.plane_rel * points[:, 2]
        seen[k, v[on], u[on]] = True
    return seen


def _seen_inside(hole: Mask, seen: Mask, planes: list[tuple[FloatArray, float]],
                 cfg: FillConfig) -> list[tuple[FloatArray, float]]:
    """The planes some of whose points fall into the hole's core: its pixels at least
    ``window_px`` // 2 + 1 px from its outline (nearer, a view's spill beside the same outline
    lands). All of them when the core is smaller than ``inside_px``: a small hole is bridged
    by its rim."""
    size = 2 * (cfg.window_px // 2 + 1) + 1
    core = cv2.erode(hole.astype(np.uint8), np.ones((size, size), np.uint8)) > 0
    if np.count_nonzero(core) < cfg.inside_px:
        return planes
    return [p for p, s in zip(planes, seen) if s[core].any()]


def _rays(K: FloatArray, h: int, w: int) -> FloatArray:
    """(h, w, 3) rays with z = 1 through each pixel."""
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    return np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones((h, w))], -1)


def _box(stat: npt.NDArray[np.int32], margin: int, h: int, w: int) -> tuple[slice, slice]:
    x, y = stat[cv2.CC_STAT_LEFT], stat[cv2.CC_STAT_TOP]
    return (slice(max(0, y - margin), min(h, y + stat[cv2.CC_STAT_HEIGHT] + margin)),
            slice(max(0, x - margin), min(w, x + stat[cv2.CC_STAT_WIDTH] + margin)))


def _hole_depth(hole: Mask, depth: FloatArray, rays: FloatArray,
                where: tuple[tuple[slice, slice], int, int],
                planes: list[tuple[FloatArray, float]], cfg: FillConfig) -> FloatArray | None:
    """
    The depth of each pixel of ``hole`` (a box of the image) on the plane of its rim, 0 where
    it runs beyond the rim's depths; None when no plane fits. The plane is the backdrop: rim
    points off it must lie in front of it (things standing before a wall), few behind, and
    those on it must lie around the hole.
    """
    size = 2 * cfg.rim_px + 1
    near = cv2.dilate(hole.astype(np.uint8), np.ones((size, size), np.uint8)) > 0
    rim = near & ~hole & (depth > 0)
    if rim.sum() < cfg.min_rim:
        return None
    outline = (cv2.dilate(hole.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0) & ~hole
    reach = cv2.dilate(rim.astype(np.uint8), np.ones((size, size), np.uint8)) > 0
    total = int(outline.sum()) + (_border_px(hole, where) if cfg.border_open else 0)
    if total == 0 or (outline & reach).sum() < cfg.enclosed * total:
        return None
    rim_rays, rim_z, rim_px = rays[rim], depth[rim], np.argwhere(rim)
    wide = cfg.min_spread * _spread(np.argwhere(hole))
    best, best_on = None, None
    for n, d in planes:
        on, behind = _sides(rim_rays, rim_z, n, d, cfg.plane_rel, cfg.behind_rel)
        if on.sum() >= cfg.min_share * len(on) and behind.mean() <= cfg.max_behind and \
                (best_on is None or on.sum() > best_on.sum()) and _spread(rim_px[on]) >= wide:
            best, best_on = (n, d), on
    if best is None:
        return None
    n, d = best
    along = rays[hole] @ n  # 1 / z = (n . ray) / d
    cos = along / np.linalg.norm(rays[hole], axis=1)
    z = np.where(cos > np.cos(np.radians(cfg.max_slant_deg)), d / np.maximum(along, 1e-12), 0.0)
    on_z = rim_z[best_on]
    z[(z < on_z.min() / (1.0 + cfg.band)) | (z > on_z.max() * (1.0 + cfg.band))] = 0.0
    if cfg.rim_hull >= 0.0:  # near the plane's rim points: a plane is not extrapolated far
        z[~_within_hull(rim_px[best_on], hole.shape, cfg.rim_hull)[hole]] = 0.0
    return z if (z > 0).mean() >= 0.5 else None


def _within_hull(px: npt.NDArray[np.intp], shape: tuple[int, ...], grow: float) -> Mask:
    """The convex hull of pixels ``px`` (row, col) in an image of ``shape``, grown by
    ``grow`` x the radius of a disc of its area."""
    inside = np.zeros(shape, np.uint8)
    hull = cv2.convexHull(px[:, ::-1].astype(np.int32))
    cv2.fillConvexPoly(inside, hull, 1)
    margin = int(round(grow * np.sqrt(cv2.contourArea(hull) / np.pi)))
    if margin > 0:
        inside = cv2.dilate(inside, cv2.getStructuringElement(cv2.MORPH_ELLIPSE,
                                                              (2 * margin + 1,) * 2))
    return inside > 0


def _spread(px: npt.NDArray[np.intp]) -> float:
    """Standard deviation of pixel positions along their narrowest direction."""
    if len(px) < 3:
        return 0.0
    return float(np.sqrt(max(np.linalg.eigvalsh(np.cov(px.T.astype(np.float64)))[0], 0.0)))


def _border_px(hole: Mask, where: tuple[tuple[slice, slice], int, int]) -> int:
    """Pixels of the hole on the image's border (its outline beyond the image)."""
    (rows, cols), h, w = where
    return int((rows.start == 0) * hole[0].sum() + (rows.stop == h) * hole[-1].sum()
               + (cols.start == 0) * hole[:, 0].sum() + (cols.stop == w) * hole[:, -1].sum())


def _sides(rays: FloatArray, z: FloatArray, n: FloatArray, d: float, rel: float,
           behind_rel: float) -> tuple[Mask, Mask]:
    """Which points (rays, depths) lie on the plane n . X = d (within ``rel`` of their depth)
    and which behind it (farther along their ray than where it crosses the plane, by more than
    ``behind_rel`` of their depth)."""
    along = dense_stereo.transform(rays, n[None, :])[:, 0]
    hit = along > 1e-12
    z_plane = np.where(hit, d / np.where(hit, along, 1.0), np.inf)
    on = np.abs(z - z_plane) <= rel * z
    return on, hit & (z > z_plane + behind_rel * z)
