"""
What the sfm node publishes, from an ``IncrementalSfm``: no ROS types, numpy only.

The published segment is the one the scale can be taken from: the segment with at least three
target vertex landmarks and the most keyframes (the current one on a tie); without such a
segment, the one with the most keyframes.
"""
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from absscale_ros.core import landmark_quality, sfm, sfm_map
from absscale_ros.core import vertex_matching as vm

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int32]
TARGET_TYPES = {'sheet': 0, 'cube': 1}  # /absscale/target_points target_type


@dataclass(frozen=True)
class TargetPoints:
    """
    Target vertex landmarks of one segment, one row each.

    :param points: (N, 3) positions, SfM units, map frame.
    :param object_ids: (N,) int32 object id (of the detection that created the landmark).
    :param vertex_ids: (N,) int32 vertex id (as the detector numbered it in that keyframe).
    :param n_obs: (N,) int32 keyframes that observed it.
    :param angle_deg: (N,) float32 widest angle between two of its viewing rays, degrees.
    :param target_types: (N,) int32 0 sheet, 1 cube.
    """

    points: FloatArray
    object_ids: IntArray
    vertex_ids: IntArray
    n_obs: IntArray
    angle_deg: npt.NDArray[np.float32]
    target_types: IntArray


def best_segment(engine: sfm.IncrementalSfm) -> sfm.Segment:
    """The segment to publish (see the module docstring)."""
    def key(i_seg: tuple[int, sfm.Segment]) -> tuple[bool, int, int]:
        i, seg = i_seg
        return seg.map.vertex_count() >= 3, len(seg.map.keyframes), i
    return max(enumerate(engine.segments), key=key)[1]


def compact(engine: sfm.IncrementalSfm) -> int:
    """
    Drop what no later keyframe reads, without changing any result; returns the maps frozen.

    The maps of the finished segments (released: nothing changes them until ``finish``) but
    the published one, read after every keyframe, are frozen (``SfmMap.freeze``: ~100 bytes a
    landmark, not ~1 KB). Keyframes whose features were forgotten lose their vertices' colour
    windows (~7 KB a vertex), which only vertex linking reads, on the newest keyframes.
    """
    best = best_segment(engine)
    frozen = 0
    for seg in engine.segments:
        if seg.map.frozen:
            continue
        for kf in seg.map.keyframes.values():
            kv = kf.vertices
            if kv is not None and not len(kf.features.points_px) and \
                    any(w is not None for w in kv.windows):
                kv.windows = [None] * len(kv.windows)
        if seg.released and seg is not best:
            seg.map.freeze()
            frozen += 1
    return frozen


def cloud(m: sfm_map.SfmMap, K: FloatArray,
          cfg: landmark_quality.CloudConfig) -> tuple[FloatArray, npt.NDArray[np.uint8]]:
    """(N, 3) well-triangulated landmarks (SfM units) and their (N, 3) uint8 RGB colours."""
    lms = [m.landmarks[i] for i in landmark_quality.well_triangulated(m, K, cfg)]
    return (np.array([lm.point_world for lm in lms]).reshape(-1, 3),
            np.array([lm.colour_rgb for lm in lms], np.uint8).reshape(-1, 3))


def cloud_observations(m: sfm_map.SfmMap, K: FloatArray, cfg: landmark_quality.CloudConfig
                       ) -> list[tuple[npt.NDArray[np.int64], FloatArray]]:
    """
    The observations of each landmark ``cloud`` publishes, in its order: the stamps (ns) of
    the keyframes that observed it and the (M, 2) undistorted px (for ground-truth benches).
    """
    out = []
    for i in landmark_quality.well_triangulated(m, K, cfg):
        obs = m.landmarks[i].obs_px
        out.append((np.array([m.keyframes[k].stamp_ns for k in obs], np.int64),
                    np.array(list(obs.values()), np.float64).reshape(-1, 2)))
    return out


def path(m: sfm_map.SfmMap) -> tuple[npt.NDArray[np.int64], FloatArray]:
    """
    Keyframe stamps and poses in stamp order.

    :returns: (N,) int64 stamps_ns and (N, 7) ``[x y z qx qy qz qw]`` (T_world_cam: camera
        centre in SfM units, quat_xyzw of the camera-to-map rotation).
    """
    kfs = sorted(m.keyframes.values(), key=lambda k: k.stamp_ns)
    stamps = np.array([k.stamp_ns for k in kfs], np.int64)
    if not kfs:
        return stamps, np.zeros((0, 7))
    from scipy.spatial.transform import Rotation  # here: see local_map.search
    T = np.array([k.T_world_cam for k in kfs])
    quat_xyzw = Rotation.from_matrix(T[:, :3, :3]).as_quat()  # scipy's order is xyzw
    return stamps, np.hstack([T[:, :3, 3], quat_xyzw])


def widest_angle_deg(point: FloatArray, centres: FloatArray) -> float:
    """
    Widest angle between the rays from ``centres`` (K, 3) to ``point`` (3,), degrees.
    """
    rays = point[None] - centres
    rays /= np.maximum(np.linalg.norm(rays, axis=1, keepdims=True), 1e-12)
    cos = np.clip(rays @ rays.T, -1.0, 1.0)
    return float(np.degrees(np.arccos(cos.min()))) if len(rays) > 1 else 0.0


def _kind(m: sfm_map.SfmMap, lm_id: int) -> str:
    for kf_id in m.landmarks[lm_id].obs_px:
        kv = m.keyframes[kf_id].vertices if kf_id in m.keyframes else None
        if kv is not None:
            hits = np.flatnonzero(kv.landmark_of == lm_id)
            if hits.size:
                return str(kv.vertices.kinds[int(hits[0])])
    return 'sheet'


def vertex_angle_deg(m: sfm_map.SfmMap, lm_id: int) -> float:
    """Widest angle between the keyframe rays to vertex landmark ``lm_id``, degrees."""
    lm = m.landmarks[lm_id]
    centres = np.array([m.keyframes[k].T_world_cam[:3, 3] for k in lm.obs_px
                        if k in m.keyframes]).reshape(-1, 3)
    return widest_angle_deg(lm.point_world, centres)


def published_vertices(m: sfm_map.SfmMap, min_angle_deg: float) -> list[int]:
    """
    The vertex landmarks published as reconstructed: seen under at least ``min_angle_deg``
    (``VertexMatchConfig.publish_min_angle_deg``). Under less, two views fix a vertex's depth
    to tens of cm at 15 m, and the scale node would not use it either.
    """
    return [lm_id for lm_id, lm in m.landmarks.items()
            if lm.label is not None and vertex_angle_deg(m, lm_id) >= min_angle_deg]


def target_points(m: sfm_map.SfmMap, min_angle_deg: float = 0.0) -> TargetPoints:
    """The published vertex landmarks of ``m`` (``published_vertices``) by object, vertex id."""
    rows = sorted((m.landmarks[lm_id].label, lm_id)
                  for lm_id in published_vertices(m, min_angle_deg))
    pts = [m.landmarks[lm_id].point_world for _, lm_id in rows]
    angles = [vertex_angle_deg(m, lm_id) for _, lm_id in rows]
    return TargetPoints(
        np.array(pts, np.float64).reshape(-1, 3),
        np.array([r[0][0] for r in rows], np.int32), np.array([r[0][1] for r in rows], np.int32),
        np.array([len(m.landmarks[r[1]].obs_px) for r in rows], np.int32),
        np.array(angles, np.float32),
        np.array([TARGET_TYPES[_kind(m, r[1])] for r in rows], np.int32))


def vertices_from_rows(rows: np.ndarray) -> vm.Vertices | None:
    """
    Detected vertices of one keyframe from ``detect.VERTEX_DTYPE``-like rows (fields u, v,
    object_id, vertex_id, target_type, and optionally score), or None when there are none.
    Vertices held from an earlier frame (``targets.HELD_SCORE``) are left out: a face alone
    is not confirmed as the cube's (in the map, held vertices moved fresh outdoor 43's scale
    error -0.62 -> -0.40 mm/m and its Table 3 max 21.7 -> 28.1 mm/m; session 20).
    """
    if rows.dtype.names and 'score' in rows.dtype.names:
        rows = rows[rows['score'] >= 0.0]
    if len(rows) == 0:
        return None
    kinds = tuple('cube' if t == TARGET_TYPES['cube'] else 'sheet' for t in rows['target_type'])
    return vm.Vertices(np.asarray(rows['object_id'], np.int64),
                       np.asarray(rows['vertex_id'], np.int64),
                       np.stack([rows['u'], rows['v']], axis=1).astype(np.float64), kinds)
