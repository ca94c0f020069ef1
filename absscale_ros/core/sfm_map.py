"""The state of one SfM map segment: keyframe poses, landmarks and their observations."""
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from absscale_ros.core import features as feat

FloatArray = npt.NDArray[np.float64]


@dataclass
class MapKeyframe:
    """
    One registered keyframe.

    :param T_world_cam: (4, 4) pose, SfM units (camera to map frame).
    :param landmark_of: (N,) landmark id of each keypoint, -1 for none.
    :param vertices: ``sfm_vertices.KeyframeVertices`` of its detected target vertices, or None.
    """

    kf_id: int
    stamp_ns: int
    T_world_cam: FloatArray
    features: feat.Features
    landmark_of: npt.NDArray[np.int64]
    vertices: Any = None


@dataclass
class Landmark:
    """
    A 3D point and its observations; a target vertex when ``label`` is (object_id, vertex_id).

    :param point_world: (3,) position, SfM units.
    :param obs_px: kf_id -> (2,) undistorted px observation.
    """

    point_world: FloatArray
    colour_rgb: tuple[int, int, int]
    obs_px: dict[int, FloatArray] = field(default_factory=dict)
    label: tuple[int, int] | None = None


@dataclass
class SfmMap:
    """Keyframes and landmarks of one map segment, with id counters (ids never reused)."""

    keyframes: dict[int, MapKeyframe] = field(default_factory=dict)
    landmarks: dict[int, Landmark] = field(default_factory=dict)
    next_landmark_id: int = 0
    dirty: set[int] = field(default_factory=set)  # landmarks observed since the graph looked

    def add_landmark(self, point_world: FloatArray, colour_rgb: tuple[int, int, int],
                     label: tuple[int, int] | None = None) -> int:
        lm_id = self.next_landmark_id
        self.next_landmark_id += 1
        self.landmarks[lm_id] = Landmark(np.asarray(point_world, np.float64), colour_rgb,
                                         label=label)
        return lm_id

    def observe(self, lm_id: int, kf_id: int, point_px: FloatArray, kp_index: int = -1) -> None:
        """Record that keyframe ``kf_id`` sees landmark ``lm_id`` at ``point_px`` (undistorted)."""
        self.landmarks[lm_id].obs_px[kf_id] = np.asarray(point_px, np.float64)
        self.dirty.add(lm_id)
        if kp_index >= 0:
            self.keyframes[kf_id].landmark_of[kp_index] = lm_id

    def unobserve(self, lm_id: int, kf_id: int) -> None:
        self.landmarks[lm_id].obs_px.pop(kf_id, None)
        lof = self.keyframes[kf_id].landmark_of
        lof[lof == lm_id] = -1

    def remove_landmark(self, lm_id: int) -> None:
        for kf_id in list(self.landmarks[lm_id].obs_px):
            self.unobserve(lm_id, kf_id)
        del self.landmarks[lm_id]

    def residuals_px(self, K: FloatArray,
                     kf_subset: set[int] | None = None) -> list[tuple[int, int, float]]:
        """
        (landmark id, keyframe id, reprojection error px) of every observation, or only of
        those in the keyframes ``kf_subset``.
        """
        lm_ids, kf_ids, uvs = [], [], []
        if kf_subset is None:
            triples = ((i, k, uv) for i, lm in self.landmarks.items()
                       for k, uv in lm.obs_px.items())
        else:  # from the keyframes' side: O(their keypoints), not O(track lengths)
            triples = ((i, k, self.landmarks[i].obs_px[k]) for k in kf_subset
                       for i in self._seen(k) if i in self.landmarks and
                       k in self.landmarks[i].obs_px)
        for lm_id, kf_id, uv in triples:
            lm_ids.append(lm_id)
            kf_ids.append(kf_id)
            uvs.append(uv)
        if not uvs:
            return []
        pts = np.array([self.landmarks[i].point_world for i in lm_ids])
        T = np.array([self.keyframes[i].T_world_cam for i in kf_ids])
        p_cam = np.einsum('nji,nj->ni', T[:, :3, :3], pts - T[:, :3, 3])
        with np.errstate(divide='ignore', invalid='ignore'):
            uv_hat = p_cam[:, :2] / p_cam[:, 2:] @ K[:2, :2].T + K[:2, 2]
        err = np.linalg.norm(uv_hat - np.array(uvs), axis=1)
        err[~(p_cam[:, 2] > 0.0)] = np.inf
        return list(zip(lm_ids, kf_ids, err.tolist()))

    def _seen(self, kf_id: int) -> set[int]:
        """Ids of the landmarks keyframe ``kf_id`` has a keypoint or a vertex of."""
        kf = self.keyframes[kf_id]
        ids = set(kf.landmark_of[kf.landmark_of >= 0].tolist())
        if kf.vertices is not None:
            ids.update(kf.vertices.landmark_of[kf.vertices.landmark_of >= 0].tolist())
        return ids

    def reprojection_rms_px(self, K: FloatArray, kf_subset: set[int] | None = None) -> float:
        """RMS reprojection error of all observations (or of those in ``kf_subset``), px."""
        errs = np.array([e for _, _, e in self.residuals_px(K, kf_subset)])
        return float(np.sqrt(np.mean(errs**2))) if errs.size else float('nan')

    def cull(self, K: FloatArray, max_px: float) -> int:
        """
        Drop observations with reprojection error over ``max_px`` (non-finite counts as over),
        then landmarks seen by fewer than two keyframes. Returns the landmarks removed.
        """
        for lm_id, kf_id, err in self.residuals_px(K):
            if not err <= max_px:
                self.unobserve(lm_id, kf_id)
        weak = [i for i, lm in self.landmarks.items() if len(lm.obs_px) < 2]
        for lm_id in weak:
            self.remove_landmark(lm_id)
        return len(weak)

    def poses(self) -> tuple[list[int], FloatArray]:
        """Keyframe ids in order and their (K, 4, 4) T_world_cam."""
        ids = sorted(self.keyframes)
        return ids, np.array([self.keyframes[i].T_world_cam for i in ids]).reshape(-1, 4, 4)

    def cloud(self) -> tuple[FloatArray, npt.NDArray[np.uint8]]:
        """(N, 3) landmark positions (SfM units) and (N, 3) uint8 RGB colours."""
        lms = list(self.landmarks.values())
        return (np.array([lm.point_world for lm in lms]).reshape(-1, 3),
                np.array([lm.colour_rgb for lm in lms], np.uint8).reshape(-1, 3))
