"""The dense cloud's point steps: per-keyframe cleaning (Open3D) and the voxel fusion."""
from typing import Any

import numpy as np
import numpy.typing as npt
import open3d as o3d

from absscale_ros.core import dense_stereo

FloatArray = npt.NDArray[np.float64]


def clean(points_cam: FloatArray, colours_bgr: npt.NDArray[np.uint8], cfg: Any) -> Any:
    """
    One keyframe's points (camera frame): voxel-downsampled, statistical outliers removed
    (``outlier_std`` 0: not), normals facing the camera. ``cfg`` has ``voxel_m``,
    ``outlier_neighbours``, ``outlier_std``, ``normal_neighbours`` (``dense_fusion.FusionConfig``).

    The statistical test compares each point's mean distance to its neighbours with all the
    others': surfaces sampled sparser (far, or seen at a grazing angle) fail it whether right
    or wrong.
    """
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points_cam))
    pc.colors = o3d.utility.Vector3dVector(colours_bgr[:, ::-1] / 255.0)
    pc = pc.voxel_down_sample(cfg.voxel_m)
    if cfg.outlier_std > 0.0 and len(pc.points) > cfg.outlier_neighbours:
        pc, _ = pc.remove_statistical_outlier(cfg.outlier_neighbours, cfg.outlier_std)
    if len(pc.points) >= 3:
        pc.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(cfg.normal_neighbours))
        pc.orient_normals_towards_camera_location(np.zeros(3))
    return pc


class VoxelSums:
    """
    The voxel average of keyframe clouds, kept as running sums per voxel, so that a new or
    moved keyframe costs its own points and not a new fusion of all the others.

    Voxels are cells of a fixed grid (``floor(p / voxel_m)``), so a cell's members do not
    change when other keyframes arrive. Each voxel holds the sums of its points, colours and
    normals and their count; a keyframe's contribution is subtracted when it is replaced.
    """

    _BITS = 21  # per axis: +-2^20 voxels (10 km at 1 cm)

    def __init__(self, voxel_m: float) -> None:
        self.voxel_m = voxel_m
        self._keys = np.zeros(0, np.int64)  # sorted voxel keys
        self._sums = np.zeros((0, 10))  # x y z, r g b, nx ny nz, count
        self._parts: dict[Any, tuple[npt.NDArray[np.int64], FloatArray]] = {}

    @property
    def parts(self) -> list[Any]:
        """The keyframes held."""
        return list(self._parts)

    def set(self, part: Any, pc: Any, T_world_cam: FloatArray) -> None:
        """Put keyframe ``part``'s cloud (camera frame, with normals) at T_world_cam, replacing
        what it held before."""
        self.remove(part)
        if not pc.has_normals() or not len(pc.points):
            return
        R, t = T_world_cam[:3, :3], T_world_cam[:3, 3]
        xyz = dense_stereo.transform(np.asarray(pc.points), R, t)
        values = np.hstack([xyz, np.asarray(pc.colors), dense_stereo.transform(
                            np.asarray(pc.normals), R),
                            np.ones((len(xyz), 1))])
        cell = np.floor(xyz / self.voxel_m).astype(np.int64) + (1 << (self._BITS - 1))
        cell = np.clip(cell, 0, (1 << self._BITS) - 1)
        keys = (cell[:, 0] << (2 * self._BITS)) | (cell[:, 1] << self._BITS) | cell[:, 2]
        keys, inverse = np.unique(keys, return_inverse=True)
        sums = np.stack([np.bincount(inverse, values[:, c], len(keys)) for c in range(10)], 1)
        self._parts[part] = (keys, sums)
        at = np.searchsorted(self._keys, keys)
        old = at < len(self._keys)
        old[old] = self._keys[at[old]] == keys[old]
        self._sums[at[old]] += sums[old]  # keys are unique: no repeated index
        self._keys = np.insert(self._keys, at[~old], keys[~old])
        self._sums = np.insert(self._sums, at[~old], sums[~old], axis=0)

    def remove(self, part: Any) -> None:
        """Take keyframe ``part``'s points out (if it has any)."""
        held = self._parts.pop(part, None)
        if held is None:
            return
        keys, sums = held
        self._sums[np.searchsorted(self._keys, keys)] -= sums
        empty = self._sums[:, 9] < 0.5
        if empty.sum() > len(empty) // 2:  # compact now and then
            self._keys, self._sums = self._keys[~empty], self._sums[~empty]

    def cloud(self) -> tuple[FloatArray, npt.NDArray[np.uint8], FloatArray]:
        """(N, 3) voxel means, m; (N, 3) rgb; (N, 3) unit normals."""
        sums = self._sums[self._sums[:, 9] > 0.5]
        mean = sums[:, :9] / sums[:, 9:]
        n = mean[:, 6:9] / np.maximum(np.linalg.norm(mean[:, 6:9], axis=1, keepdims=True), 1e-12)
        colours = np.clip(np.round(mean[:, 3:6] * 255.0), 0, 255).astype(np.uint8)
        return mean[:, :3], colours, n
