"""
Which landmarks of a map are well triangulated: enough views, a wide enough angle between
them, a small reprojection error in every view, (``max_sigma_rel``) a small estimated
position uncertainty, (``max_plane_rel``) a place on the surface its neighbours lie on and
(``max_incidence_deg``) a view of that surface from not too grazing an angle. Only these are
published, so that lengths measured between published points are trustworthy (the
paper's Table 3); the map itself keeps the rest (they still help register the next keyframes).

The uncertainty is a surveyor's: the standard deviation along the worst axis of the point's
error ellipsoid, from its viewing geometry (the triangulation's Jacobians at the map's poses)
and its pixel noise (its own residuals, at least ``min_noise_px``), relative to the map's
median viewing distance (over the landmarks seen ``min_observations`` times: the map has no
metric scale). On the tuning bags the landmarks' error against the true surface grows with it
(rank correlation ~0.4; re-triangulating on the true poses leaves the error unchanged indoors:
it is the observations' noise, not the poses').
"""
from dataclasses import dataclass
from itertools import chain, compress

import numpy as np
import numpy.typing as npt

from absscale_ros.core import sfm_map

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class CloudConfig:
    """Thresholds a landmark must pass to be published."""

    # Defaults measured on simulator bags (landmark depth error against the true surface):
    # these keep ~30 % of the landmarks and cut the 90th percentile by 15-35 %.
    min_observations: int = 3  # keyframes that see it
    min_angle_deg: float = 5.0  # widest angle between two of its viewing rays, degrees
    max_reproj_px: float = 1.0  # largest reprojection error over its observations, px
    # Largest position standard deviation (worst axis) over the map's median viewing distance
    # (0: off); the pixel noise is the landmark's residual RMS (dof-corrected), at least
    # ``min_noise_px``.
    max_sigma_rel: float = 0.0
    min_noise_px: float = 0.5
    # Largest distance from the plane through the landmark's ``plane_neighbours`` nearest
    # landmarks (those seen ``min_observations`` times) over its mean viewing distance (0: off).
    # A feature whose observations slide along its track (an edge, a low-contrast blob, a
    # junction of two surfaces) is triangulated off the surface its neighbours lie on, while
    # its residuals stay small.
    max_plane_rel: float = 0.0
    plane_neighbours: int = 16
    # Largest angle between the landmark's mean viewing direction and the normal of that same
    # neighbours' plane, degrees (0: off). On a surface seen at a grazing angle (far floor)
    # the texture is foreshortened, and differently in each view as the camera moves: the
    # keypoint slides along the track, which the map fits as depth, along the ray and so
    # nearly within the plane, where ``max_plane_rel`` cannot see it.
    max_incidence_deg: float = 0.0

    def __post_init__(self) -> None:
        if self.min_observations < 2 or self.min_angle_deg < 0.0 or self.max_reproj_px <= 0.0 \
                or self.max_sigma_rel < 0.0 or self.min_noise_px <= 0.0 or \
                self.max_plane_rel < 0.0 or self.plane_neighbours < 3 or \
                not 0.0 <= self.max_incidence_deg < 90.0:
            raise ValueError(f'bad cloud config {self}')


def well_triangulated(m: sfm_map.SfmMap, K: FloatArray, cfg: CloudConfig) -> list[int]:
    """Ids of the landmarks of ``m`` that pass ``cfg``, in the map's order."""
    # Run after every keyframe over the whole segment: built with as little Python per
    # observation as will do (map, chain and fromiter rather than generator loops).
    lms_of = m.landmarks
    ids = [i for i, lm in lms_of.items() if len(lm.obs_px) >= cfg.min_observations]
    if not ids:
        return []
    lms = list(map(lms_of.__getitem__, ids))
    obs = [lm.obs_px for lm in lms]
    counts = np.fromiter(map(len, obs), np.int64, len(obs))
    kf_order = {k: n for n, k in enumerate(m.keyframes)}
    kf_row = np.fromiter(map(kf_order.__getitem__, chain.from_iterable(obs)), np.int64,
                         counts.sum())
    uv = np.concatenate(list(chain.from_iterable(map(dict.values, obs)))).reshape(-1, 2)
    T = np.array([kf.T_world_cam for kf in m.keyframes.values()])[kf_row]
    pts = np.repeat(np.array([lm.point_world for lm in lms]), counts, axis=0)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    p_cam = np.einsum('nji,nj->ni', T[:, :3, :3], pts - T[:, :3, 3])
    with np.errstate(divide='ignore', invalid='ignore'):
        err = np.linalg.norm(p_cam[:, :2] / p_cam[:, 2:] @ K[:2, :2].T + K[:2, 2] - uv, axis=1)
    err[~(p_cam[:, 2] > 0.0)] = np.inf
    ok = (np.maximum.reduceat(err, starts) <= cfg.max_reproj_px) & \
        (_widest_angles_deg(pts, T, counts, starts) >= cfg.min_angle_deg)
    surface = cfg.max_plane_rel > 0.0 or cfg.max_incidence_deg > 0.0
    if (cfg.max_sigma_rel > 0.0 or surface) and ok.any():
        # each landmark's mean viewing distance, which both gates are relative to
        dist = np.add.reduceat(np.linalg.norm(pts - T[:, :3, 3], axis=1), starts) / counts
    if cfg.max_sigma_rel > 0.0 and ok.any():
        scene = float(np.median(dist))
        rows = np.repeat(ok, counts)  # only the landmarks still in: the Jacobians cost most
        sub = counts[ok]
        sub_starts = np.concatenate([[0], np.cumsum(sub)[:-1]])
        ok[ok] = sigma(T[rows], p_cam[rows], err[rows], K, sub, sub_starts,
                       cfg.min_noise_px) <= cfg.max_sigma_rel * scene
    if surface and ok.any():
        rows = np.flatnonzero(ok)
        off, normal = neighbours_plane(pts[starts], rows, cfg.plane_neighbours)
        keep = np.ones(len(rows), bool)
        if cfg.max_plane_rel > 0.0:
            keep &= off <= cfg.max_plane_rel * dist[rows]
        if cfg.max_incidence_deg > 0.0:
            keep &= ~(incidence_cos(pts, T, starts, rows, normal) <
                      np.cos(np.radians(cfg.max_incidence_deg)))
        ok[rows] = keep
    return list(compress(ids, ok.tolist()))


def incidence_cos(pts: FloatArray, T: FloatArray, starts: npt.NDArray[np.int64],
                  rows: npt.NDArray[np.int64], normal: FloatArray) -> FloatArray:
    """
    (len(rows),) |cosine| between the unit ``normal`` (len(rows), 3) of each landmark ``rows``
    and its mean viewing direction (observations grouped by landmark, as in
    ``well_triangulated``): 1 head-on, 0 grazing; NaN where the normal is.
    """
    rays = pts - T[:, :3, 3]
    rays /= np.maximum(np.linalg.norm(rays, axis=1, keepdims=True), 1e-12)
    mean = np.add.reduceat(rays, starts)[rows]
    return np.abs(np.sum(mean * normal, axis=1)) / \
        np.maximum(np.linalg.norm(mean, axis=1), 1e-12)


def neighbours_plane(points: FloatArray, rows: npt.NDArray[np.int64], neighbours: int
                     ) -> tuple[FloatArray, FloatArray]:
    """
    The least-squares plane through the ``neighbours`` nearest other points of ``points``
    (N, 3) of each of ``points[rows]``: (len(rows),) the point's distance from it and
    (len(rows), 3) its unit normal (NaN with fewer than 3 other points).
    """
    from scipy.spatial import cKDTree
    k = min(neighbours, len(points) - 1)
    if k < 3:
        return np.zeros(len(rows)), np.full((len(rows), 3), np.nan)
    _, idx = cKDTree(points).query(points[rows], k + 1)
    # Each point finds itself (among its nearest): move it last and leave it out.
    idx = np.take_along_axis(idx, np.argsort(idx == rows[:, None], axis=1, kind='stable'),
                             axis=1)[:, :k]
    nb = points[idx]
    centre = nb.mean(axis=1)
    nb = nb - centre[:, None]
    normal = np.linalg.eigh(np.einsum('nki,nkj->nij', nb, nb))[1][:, :, 0]
    return np.abs(np.sum((points[rows] - centre) * normal, axis=1)), normal


def sigma(T: FloatArray, p_cam: FloatArray, err: FloatArray, K: FloatArray,
          counts: npt.NDArray[np.int64], starts: npt.NDArray[np.int64],
          min_noise_px: float) -> FloatArray:
    """
    (N,) standard deviation of each landmark's position along its worst axis, map units, the
    poses held; observations grouped by landmark, as in ``well_triangulated``.

    :param T: (O, 4, 4) T_world_cam of each observation's keyframe.
    :param p_cam: (O, 3) the landmark in that camera; ``err`` (O,) its residual, px.
    """
    z = p_cam[:, 2]
    J = np.zeros((len(z), 2, 3))  # d(px)/d(camera point), then rotated to the world
    with np.errstate(divide='ignore', invalid='ignore'):
        J[:, 0, 0], J[:, 1, 1] = K[0, 0] / z, K[1, 1] / z
        J[:, 0, 2], J[:, 1, 2] = -K[0, 0] * p_cam[:, 0] / z**2, -K[1, 1] * p_cam[:, 1] / z**2
    J = np.einsum('nij,nkj->nik', J, T[:, :3, :3])
    info = np.add.reduceat(np.einsum('nji,njk->nik', J, J), starts)
    least = np.linalg.eigvalsh(info)[:, 0]  # the worst axis has the least information
    worst = np.full(len(counts), np.inf)
    worst[least > 0.0] = 1.0 / np.sqrt(least[least > 0.0])
    noise = np.sqrt(np.add.reduceat(err**2, starts) /
                    np.maximum(2.0 * counts - 3.0, 1.0))  # residual RMS per degree of freedom
    return worst * np.maximum(noise, min_noise_px)


def _widest_angles_deg(pts: FloatArray, T: FloatArray, counts: npt.NDArray[np.int64],
                       starts: npt.NDArray[np.int64]) -> FloatArray:
    """
    Widest ray angle per landmark (observations grouped by landmark): from the ray furthest
    from the group's mean direction to the ray furthest from it, which is the widest pair
    when the cameras lie along a path (exact for rays in one plane).
    """
    rays = pts - T[:, :3, 3]
    rays /= np.maximum(np.linalg.norm(rays, axis=1, keepdims=True), 1e-12)
    group = np.repeat(np.arange(len(counts)), counts)
    mean = np.add.reduceat(rays, starts)[group]
    # The ray least aligned with its group's mean (the first of equals; NaN last, as a sort
    # would put them): a minimum per group, without sorting every observation.
    closeness = np.sum(rays * mean, axis=1)
    least = np.fmin.reduceat(closeness, starts)[group]
    first = np.minimum.reduceat(np.where(closeness == least, np.arange(len(rays)), len(rays)),
                                starts)
    first = np.where(first == len(rays), starts, first)  # a group of NaN only: its first
    cos = np.minimum.reduceat(np.sum(rays * rays[first][group], axis=1), starts)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
