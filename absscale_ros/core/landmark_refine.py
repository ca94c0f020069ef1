"""
Sub-pixel refinement of a landmark's observations by patch alignment at full resolution (for
the Table 3 lengths of issue #7).

SIFT runs on a 640 px copy; its observations of one landmark disagree by ~0.5-0.7 px (median,
against the ground truth transferred between simulator keyframes). Here the patch around the
landmark's reference observation is warped into another keyframe through the landmark's local
plane (normal from its neighbouring landmarks), and Lucas-Kanade finds the remaining shift. On
the outdoor tuning bag 51 that cut the disagreement from 0.48 to 0.18 px (median) and, with
every observation refined and the landmarks re-triangulated on the map's poses, the Table 3
mean at the true scale from 5.6 to 3.6 mm/m; indoors (blurred, low-contrast desk and walls)
alignment fails its forward-backward check for most observations and gains little (6.2 to
5.8 mm/m when only fully refined landmarks take it). A fronto-parallel warp is worse than the
detections (0.77 px). ``IncrementalSfm`` refines each keyframe's observations before its
graph update (``RefineConfig.max_observations``), so the bundle adjustment uses them too.
"""
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core.types import CameraModel

FloatArray = npt.NDArray[np.float64]
Grey = npt.NDArray[np.uint8]
_MAX_ROWS = 2**15 - 1  # cv2.remap takes images of fewer than 2^15 rows


@dataclass(frozen=True)
class RefineConfig:
    """Patch alignment settings (full-resolution pixels)."""

    # Observations refined per keyframe, those of the landmarks with the most views first
    # (0: off). A landmark's observations are aligned to its oldest one whose keyframe image is
    # still kept; each (landmark, keyframe) once.
    max_observations: int = 0
    keep_images: int = 8  # newest keyframes whose undistorted grey image is kept (~0.9 MB each)
    min_views: int = 3  # landmarks seen by fewer keyframes are left alone (rarely published)
    half_patch_px: int = 15  # patch compared: (2 r + 1)^2 around the reference observation
    margin_px: int = 6  # search margin around the predicted position, px
    window_px: int = 21  # Lucas-Kanade window
    max_fb_px: float = 0.3  # forward-backward disagreement above which alignment failed
    neighbours: int = 12  # landmarks whose plane gives a landmark's normal

    def __post_init__(self) -> None:
        if self.max_observations < 0 or self.keep_images < 2 or self.min_views < 2 or \
                self.half_patch_px < 3 or self.margin_px < 2 or self.window_px < 5 or \
                self.max_fb_px <= 0.0 or self.neighbours < 3:
            raise ValueError(f'bad refine config {self}')


def undistort_maps(camera: CameraModel) -> tuple[npt.NDArray[np.float32], ...]:
    """Remap tables from a distorted image to the pinhole image of the same ``K``."""
    return cv2.initUndistortRectifyMap(camera.K, camera.dist, None, camera.K,
                                       (camera.width, camera.height), cv2.CV_32FC1)


def undistorted_grey(image_bgr: npt.NDArray[np.uint8],
                     maps: tuple[npt.NDArray[np.float32], ...] | None) -> Grey:
    """(H, W) uint8 grey image in undistorted pixels (where observations live)."""
    grey = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2GRAY)
    return grey if maps is None else cv2.remap(grey, maps[0], maps[1], cv2.INTER_LINEAR)


def plane_normals(points: FloatArray, cloud: FloatArray, neighbours: int) -> FloatArray:
    """
    (N, 3) unit normal of the plane through each point's ``neighbours`` nearest points of
    ``cloud`` (M, 3) (smallest principal direction).
    """
    from scipy.spatial import cKDTree
    k = min(neighbours, len(cloud))
    _, idx = cKDTree(cloud).query(points, k)
    nb = cloud[np.asarray(idx).reshape(len(points), k)]
    nb = nb - nb.mean(axis=1, keepdims=True)
    return np.linalg.eigh(np.einsum('nki,nkj->nij', nb, nb))[1][:, :, 0]


def tile_size(cfg: RefineConfig) -> int:
    """Side of the square tile around an observation that ``align`` compares, px."""
    return 2 * (cfg.half_patch_px + cfg.margin_px) + 1


def ref_tiles(ref: Grey, uv_ref: FloatArray, cfg: RefineConfig) -> Grey:
    """
    (N, s, s) tiles of ``ref`` centred on ``uv_ref`` (N, 2) undistorted px, bilinear: what
    ``align`` compares with the other keyframe. A landmark is aligned to the same reference
    observation in several keyframes, so its tile can be kept (the same pixels as here).
    """
    n, s = len(uv_ref), tile_size(cfg)
    grid = np.arange(s, dtype=np.float64) - (s - 1) // 2
    u = (uv_ref[:, 0, None, None] + grid[None, None, :]).astype(np.float32)
    v = (uv_ref[:, 1, None, None] + grid[None, :, None]).astype(np.float32)
    u, v = np.broadcast_to(u, (n, s, s)), np.broadcast_to(v, (n, s, s))
    out = [cv2.remap(ref, u[c:c + k].reshape(k * s, s), v[c:c + k].reshape(k * s, s),
                     cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
           for c, k in _chunks([(0, n)], _MAX_ROWS // s)]
    out = np.concatenate(out) if out else np.zeros((0, s), np.uint8)
    return out.reshape(n, s, s)


def align(ref: Grey, img: Grey, T_ref: FloatArray, T_img: FloatArray, K: FloatArray,
          points: FloatArray, normals: FloatArray, uv_ref: FloatArray,
          cfg: RefineConfig, tiles: Grey | None = None
          ) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """
    Where the patches around ``uv_ref`` in ``ref`` appear in ``img``.

    Each patch is warped through the plane (``points``, ``normals``, world frame) into ``img``;
    all patches go into one mosaic so that one Lucas-Kanade call (and one back) aligns them.

    :param T_ref, T_img: (4, 4) T_world_cam of the two keyframes.
    :param uv_ref: (N, 2) undistorted px in ``ref``.
    :param tiles: ``ref_tiles(ref, uv_ref, cfg)`` if kept from before (None: made here).
    :returns: (N, 2) undistorted px in ``img``, and (N,) whether alignment succeeded.
    """
    if tiles is None:
        tiles = _cut(ref, uv_ref, cfg)
    return align_pairs([(img, T_ref, T_img, len(points))], K, points, normals, uv_ref, tiles,
                       cfg)


def _cut(ref: Grey, uv_ref: FloatArray, cfg: RefineConfig) -> Grey:
    """``ref_tiles`` in parts that ``cv2.remap`` takes (fewer than 2^15 rows)."""
    most = (2**15 - 1) // tile_size(cfg)
    return np.concatenate([ref_tiles(ref, uv_ref[a:a + most], cfg)
                           for a in range(0, max(len(uv_ref), 1), most)])


def _homographies(T_ref: FloatArray, T_img: FloatArray, K: FloatArray, K_inv: FloatArray,
                  points: FloatArray, normals: FloatArray) -> tuple[FloatArray, ...]:
    """
    Per patch of one keyframe pair: the plane's homography a -> b and the fronto-parallel one
    (N, 3, 3), the plane's ``num`` and the point's depth in a (N,), and ``n_k`` (N, 3).

    Ray-plane depth at a pixel of a is num / (n_a . ray), with ray = K^-1 (u, v, 1) (z = 1),
    so the plane maps a to b by the homography K (num R + t n_a^T) K^-1 (R, t: a -> b); a
    depth off the plane's plausible range is replaced by the point's own (fronto-parallel:
    K (z R + t e_z^T) K^-1). Both per patch, evaluated on the tile's pixels: no per-pixel
    rays or 3D points. n_a . ray = n_k . (u, v, 1): linear in the pixel.
    """
    R_a, t_a, R_b, t_b = T_ref[:3, :3], T_ref[:3, 3], T_img[:3, :3], T_img[:3, 3]
    R, t = R_b.T @ R_a, R_b.T @ (t_a - t_b)
    n_a = normals @ R_a  # the planes in camera a
    p_a = (points - t_a) @ R_a
    num, z_pt = np.sum(n_a * p_a, axis=1), p_a[:, 2]
    plane = K @ (num[:, None, None] * R + t[:, None] * n_a[:, None, :]) @ K_inv
    flat = K @ (z_pt[:, None, None] * R + np.outer(t, [0.0, 0.0, 1.0])) @ K_inv
    return plane, flat, num, z_pt, n_a @ K_inv


class _Warps:
    """The plane-induced homographies of N patches, with the fronto-parallel fallback for
    pixels whose plane depth is implausible (``_homographies`` of each pair, concatenated)."""

    def __init__(self, pairs: list[tuple[Grey, FloatArray, FloatArray, int]], K: FloatArray,
                 points: FloatArray, normals: FloatArray, spans: list[tuple[int, int]]):
        K_inv = np.linalg.inv(K)
        self.plane, self.flat, self.num, self.z_pt, self.n_k = (np.concatenate(x) for x in zip(*[
            _homographies(T_ref, T_img, K, K_inv, points[a:b], normals[a:b])
            for (_, T_ref, T_img, _), (a, b) in zip(pairs, spans)]))

    @staticmethod
    def apply(H: FloatArray, u: FloatArray, v: FloatArray, dtype: type = np.float64
              ) -> tuple[FloatArray, FloatArray]:
        """Pixels of a through the (N, 3, 3) homographies: u (N, 1, S) and v (N, R, 1) (or
        both (N, R, S)) give (N, R, S) of ``dtype``, the float64 quotient rounded (separable:
        one full-size sum per row of H, into as few full-size arrays as it takes: allocating
        them was most of the warp's time)."""
        h = H[:, :, :, None, None]
        w = h[:, 2, 0] * u + (h[:, 2, 1] * v + h[:, 2, 2])
        t = h[:, 0, 0] * u + (h[:, 0, 1] * v + h[:, 0, 2])
        ub = np.divide(t, w, out=np.empty(w.shape, dtype))
        np.add(h[:, 1, 0] * u, h[:, 1, 1] * v + h[:, 1, 2], out=t)
        return ub, np.divide(t, w, out=t if dtype is np.float64 else np.empty(w.shape, dtype))

    def on_plane(self, rows: npt.NDArray[np.int64], u: FloatArray, v: FloatArray
                 ) -> npt.NDArray[np.bool_]:
        """Whether the plane's depth at the pixels (u, v) of patches ``rows`` is plausible."""
        c = self.n_k[rows][:, :, None, None]
        with np.errstate(divide='ignore', invalid='ignore'):
            depth = self.num[rows, None, None] / (c[:, 0] * u + (c[:, 1] * v + c[:, 2]))
        z = self.z_pt[rows, None, None]
        return np.isfinite(depth) & (depth > 0.2 * z) & (depth < 5.0 * z)

    def pixels(self, mixed: npt.NDArray[np.int64], u: FloatArray, v: FloatArray,
               dtype: type = np.float64) -> tuple[FloatArray, FloatArray]:
        """``apply`` of the plane warps; the ``mixed`` patches' off-plane pixels through the
        fronto-parallel ones instead."""
        ub, vb = self.apply(self.plane, u, v, dtype)
        if len(mixed):
            ok = self.on_plane(mixed, u[mixed], v[mixed])
            fu, fv = self.apply(self.flat[mixed], u[mixed], v[mixed])
            ub[mixed] = np.where(ok, ub[mixed], fu)  # on the plane: already there
            vb[mixed] = np.where(ok, vb[mixed], fv)
        return ub, vb


def _chunks(spans: list[tuple[int, int]], most: int) -> list[tuple[int, int]]:
    """(start, count) of runs of at most ``most`` patches, never across a pair."""
    return [(c, min(most, b - c)) for a, b in spans for c in range(a, b, most)]


def _lucas_kanade(tiles: Grey, warped: Grey, spans: list[tuple[int, int]], cfg: RefineConfig
                  ) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """Shift of each warped tile against its reference tile (N, 2), and whether it is
    trusted: both directions tracked, agreeing within ``max_fb_px``, inside the margin."""
    n, s, r, m = len(tiles), tile_size(cfg), cfg.half_patch_px, cfg.margin_px
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.001)
    win = (cfg.window_px, cfg.window_px)
    fwd, back, ok_f, ok_b = [], [], [], []
    # One mosaic per pair (each patch's tile below the previous one's): LK's float32
    # positions lose precision further down a taller mosaic.
    for c, k in _chunks(spans, _MAX_ROWS // s):
        A_c, B_c = tiles[c:c + k].reshape(k * s, s), warped[c:c + k].reshape(k * s, s)
        centre = np.stack([np.full(k, r + m), r + m + s * np.arange(k)], 1).astype(
            np.float32)[:, None]
        f, okf, _ = cv2.calcOpticalFlowPyrLK(A_c, B_c, centre, None, winSize=win, maxLevel=0,
                                             criteria=crit)
        bk, okb, _ = cv2.calcOpticalFlowPyrLK(B_c, A_c, f, centre.copy(), winSize=win,
                                              maxLevel=0, flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
                                              criteria=crit)
        fwd.append(f - centre)
        back.append(bk - centre)
        ok_f.append(okf)
        ok_b.append(okb)
    shift = np.concatenate(fwd).reshape(n, 2).astype(np.float64)
    ok = np.concatenate(ok_f).ravel().astype(bool) & np.concatenate(ok_b).ravel().astype(bool) & \
        (np.linalg.norm(np.concatenate(back).reshape(n, 2), axis=1) < cfg.max_fb_px) & \
        (np.abs(shift).max(axis=1) < m - 1)
    return shift, ok


def align_pairs(pairs: list[tuple[Grey, FloatArray, FloatArray, int]], K: FloatArray,
                points: FloatArray, normals: FloatArray, uv_ref: FloatArray, tiles: Grey,
                cfg: RefineConfig) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """
    ``align`` for several keyframe pairs at once: the warps and their inverse for all patches
    together (a keyframe refines ~300 observations in ~15 pairs: numpy's per-call work was
    about a third of the alignment's CPU).

    :param pairs: (img, T_ref, T_img, count) of each pair; its ``count`` patches follow the
        previous pair's in ``points``, ``normals``, ``uv_ref`` and ``tiles``.
    :param tiles: (N, s, s) ``ref_tiles`` of each patch in its reference image.
    :returns: as ``align``, for all N patches in order.
    """
    n, r, m = len(points), cfg.half_patch_px, cfg.margin_px
    if n == 0:
        return np.zeros((0, 2)), np.zeros(0, bool)
    if sum(p[3] for p in pairs) != n:
        raise ValueError(f'the pairs hold {sum(p[3] for p in pairs)} patches, not {n}')
    s = tile_size(cfg)
    grid = np.arange(-(r + m), r + m + 1, dtype=np.float64)
    bounds = np.cumsum([0] + [p[3] for p in pairs]).tolist()
    spans = list(zip(bounds[:-1], bounds[1:]))
    warps = _Warps(pairs, K, points, normals, spans)
    u_a = uv_ref[:, 0, None, None] + grid[None, None, :]  # (N, 1, s) and (N, s, 1): the tile
    v_a = uv_ref[:, 1, None, None] + grid[None, :, None]
    # The depth's inverse is linear in the pixel, so a patch whose 4 tile corners are on the
    # plane is so everywhere; only the others are checked pixel by pixel.
    ends = grid[[0, -1]]
    corners = warps.on_plane(np.arange(n), uv_ref[:, 0, None, None] + ends[None, None, :],
                             uv_ref[:, 1, None, None] + ends[None, :, None])
    mixed = np.flatnonzero(~corners.all(axis=(1, 2)))
    u_b, v_b = warps.pixels(mixed, u_a, v_a, np.float32)  # the remap's maps
    warped = np.concatenate([
        cv2.remap(img, u_b[c:c + k].reshape(-1, s), v_b[c:c + k].reshape(-1, s),
                  cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        for (img, *_), span in zip(pairs, spans) for c, k in _chunks([span], _MAX_ROWS // s)
    ]).reshape(n, s, s)
    shift, ok = _lucas_kanade(tiles, warped, spans, cfg)
    # The aligned tile position, mapped back through the warp (bilinear in the tile).
    x = np.clip(shift[:, 0] + r + m, 0.0, s - 1.001)
    y = np.clip(shift[:, 1] + r + m, 0.0, s - 1.001)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    # The warp at the 4 tile pixels around it, (N, 2, 2): rows y0, y0 + 1; columns x0, x0 + 1.
    cu = uv_ref[:, 0, None, None] + grid[np.stack([x0, x0 + 1], 1)][:, None, :]
    cv = uv_ref[:, 1, None, None] + grid[np.stack([y0, y0 + 1], 1)][:, :, None]
    ub, vb = warps.pixels(mixed, cu, cv)

    def at(M: FloatArray) -> FloatArray:
        return ((1 - fx) * (1 - fy) * M[:, 0, 0] + fx * (1 - fy) * M[:, 0, 1] +
                (1 - fx) * fy * M[:, 1, 0] + fx * fy * M[:, 1, 1])
    return np.stack([at(ub), at(vb)], axis=1), ok
