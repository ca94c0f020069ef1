"""Open3D steps of the dense cloud: per-keyframe cleaning and the voxel fusion of keyframes."""
from typing import Any

import numpy as np
import numpy.typing as npt
import open3d as o3d

FloatArray = npt.NDArray[np.float64]


def clean(points_cam: FloatArray, colours_bgr: npt.NDArray[np.uint8], cfg: Any) -> Any:
    """
    One keyframe's points (camera frame): voxel-downsampled, statistical outliers removed,
    normals facing the camera. ``cfg`` has ``voxel_m``, ``outlier_neighbours``,
    ``outlier_std``, ``normal_neighbours`` (``dense_fusion.FusionConfig``).
    """
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points_cam))
    pc.colors = o3d.utility.Vector3dVector(colours_bgr[:, ::-1] / 255.0)
    pc = pc.voxel_down_sample(cfg.voxel_m)
    if len(pc.points) > cfg.outlier_neighbours:
        pc, _ = pc.remove_statistical_outlier(cfg.outlier_neighbours, cfg.outlier_std)
    if len(pc.points) >= 3:
        pc.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(cfg.normal_neighbours))
        pc.orient_normals_towards_camera_location(np.zeros(3))
    return pc


def fuse(parts: list[tuple[Any, FloatArray]], voxel_m: float) -> tuple[
        FloatArray, npt.NDArray[np.uint8], FloatArray]:
    """
    The voxel average of keyframe clouds, each placed by its T_world_cam.

    :returns: (N, 3) points, m; (N, 3) rgb; (N, 3) unit normals.
    """
    xyz, rgb, nrm = [], [], []
    for pc, T in parts:
        if not pc.has_normals() or not len(pc.points):
            continue
        R, t = T[:3, :3], T[:3, 3]
        xyz.append(np.asarray(pc.points) @ R.T + t)
        nrm.append(np.asarray(pc.normals) @ R.T)
        rgb.append(np.asarray(pc.colors))
    if not xyz:
        return np.zeros((0, 3)), np.zeros((0, 3), np.uint8), np.zeros((0, 3))
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.concatenate(xyz)))
    pc.colors = o3d.utility.Vector3dVector(np.concatenate(rgb))
    pc.normals = o3d.utility.Vector3dVector(np.concatenate(nrm))
    pc = pc.voxel_down_sample(voxel_m)
    n = np.asarray(pc.normals)
    n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    colours = np.clip(np.round(np.asarray(pc.colors) * 255.0), 0, 255).astype(np.uint8)
    return np.asarray(pc.points), colours, n
