"""
Accuracy and completeness of a dense cloud against a known scene mesh (simulator truth).

Accuracy: distance of each dense point to the true surface, after a *rigid* (not scaled)
alignment of the metric keyframe trajectory to the true one, so a scale error counts.
Completeness: of the true surface points that at least two keyframes see, the fraction with a
dense point within a radius, also per fifth of them by depth (two-view precision falls with
depth squared: the far fifths are where completeness is lost). Visibility is decided by ray
casting the mesh from each keyframe.
"""
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt
import open3d as o3d
from scipy.spatial import cKDTree

from absscale_ros.core.types import CameraModel

FloatArray = npt.NDArray[np.float64]


def rigid_alignment(src: FloatArray, dst: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Least-squares rotation and translation with ``dst ~ R @ src + t`` (no scale)."""
    mu_s, mu_d = src.mean(0), dst.mean(0)
    U, _, Vt = np.linalg.svd((dst - mu_d).T @ (src - mu_s))
    S = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ S @ Vt
    return R, mu_d - R @ mu_s


class SceneMesh:
    """The true scene surface: distances and visibility by Open3D ray casting."""

    def __init__(self, vertices_m: FloatArray, triangles: npt.NDArray[np.integer]) -> None:
        self._rc = o3d.t.geometry.RaycastingScene()
        self._rc.add_triangles(o3d.core.Tensor(np.asarray(vertices_m, np.float32)),
                               o3d.core.Tensor(np.asarray(triangles, np.uint32)))

    def distance(self, points: FloatArray) -> npt.NDArray[np.float32]:
        """Unsigned distance of each point to the surface, m."""
        return self._rc.compute_distance(o3d.core.Tensor(np.asarray(points, np.float32))).numpy()

    def visible_from(self, points: FloatArray, T_world_cam: FloatArray,
                     camera: CameraModel) -> npt.NDArray[np.bool_]:
        """Which surface points one camera sees: in its image and not hidden by the mesh."""
        R, c = T_world_cam[:3, :3], T_world_cam[:3, 3]
        p_cam = (points - c) @ R
        ok = p_cam[:, 2] > 0.05
        px, _ = cv2.projectPoints(p_cam.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), camera.K,
                                  camera.dist if camera.has_distortion else None)
        px = px.reshape(-1, 2)
        ok &= (px[:, 0] >= 0) & (px[:, 0] <= camera.width - 1) & \
            (px[:, 1] >= 0) & (px[:, 1] <= camera.height - 1)
        ray = points - c
        dist = np.linalg.norm(ray, axis=1)
        rays = np.concatenate([np.broadcast_to(c, ray.shape), ray / dist[:, None]], axis=1)
        hit = self._rc.cast_rays(o3d.core.Tensor(rays.astype(np.float32)))['t_hit'].numpy()
        return ok & (hit >= dist * (1 - 1e-3) - 1e-3)


@dataclass(frozen=True)
class DenseScore:
    """Figures of one dense cloud (distances in metres, fractions 0..1)."""

    points: int
    median_scene_depth_m: float
    distance_median_m: float
    distance_p90_m: float
    completeness: float
    surface_samples: int
    # completeness per fifth of the samples by depth, nearest first, and the fifths' edges, m
    completeness_by_depth: tuple[float, ...] = ()
    depth_fifths_m: tuple[float, ...] = ()

    @property
    def median_rel(self) -> float:
        return self.distance_median_m / self.median_scene_depth_m

    @property
    def p90_rel(self) -> float:
        return self.distance_p90_m / self.median_scene_depth_m


def score(points: FloatArray, mesh: SceneMesh, samples: FloatArray, sample_depths: FloatArray,
          radius_m: float) -> DenseScore:
    """
    :param points: (N, 3) dense points already in the true world frame.
    :param samples: (M, 3) true surface points seen by at least two keyframes.
    :param sample_depths: their depths in the keyframe they were sampled from (scene depth).
    """
    d = mesh.distance(points) if len(points) else np.array([np.inf])
    near = cKDTree(points).query(samples, distance_upper_bound=radius_m)[0] \
        if len(points) and len(samples) else np.full(len(samples), np.inf)
    found = np.isfinite(near)
    edges = np.quantile(sample_depths, np.linspace(0.0, 1.0, 6)) if len(samples) else []
    band = np.clip(np.searchsorted(edges, sample_depths, side='right') - 1, 0, 4)
    return DenseScore(len(points), float(np.median(sample_depths)), float(np.median(d)),
                      float(np.percentile(d, 90)), float(np.mean(found)), len(samples),
                      tuple(float(np.mean(found[band == k])) for k in range(5)
                            if len(samples)),
                      tuple(float(e) for e in edges))
