"""
The state of one SfM map segment: keyframe poses, landmarks and their observations.

A finished segment's landmarks can be packed into arrays (``SfmMap.freeze``: ~10x less memory
than ~1 KB of Python objects per landmark, which made a long scan's memory grow); any access to
``landmarks`` unpacks them again, exactly as they were.
"""
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


@dataclass(slots=True)  # no __dict__: ~100 bytes less per landmark
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


@dataclass(frozen=True)
class PackedLandmarks:
    """
    Landmarks as arrays, in the map's order; observations grouped by landmark.

    :param ids: (M,) int64 landmark ids.
    :param points_world: (M, 3) float64 positions, SfM units.
    :param colours_rgb: (M, 3) uint8.
    :param labels: (M, 2) int64 (object_id, vertex_id); rows of unlabelled landmarks unused.
    :param labelled: (M,) bool, whether the landmark has a label.
    :param obs_starts: (M + 1,) int64 first observation row of each landmark, then the total.
    :param obs_kf_ids: (O,) int64 keyframe of each observation.
    :param obs_px: (O, 2) float64 undistorted px.
    """

    ids: npt.NDArray[np.int64]
    points_world: FloatArray
    colours_rgb: npt.NDArray[np.uint8]
    labels: npt.NDArray[np.int64]
    labelled: npt.NDArray[np.bool_]
    obs_starts: npt.NDArray[np.int64]
    obs_kf_ids: npt.NDArray[np.int64]
    obs_px: FloatArray


def pack(landmarks: dict[int, Landmark]) -> PackedLandmarks:
    """The arrays of ``landmarks`` (see ``PackedLandmarks``)."""
    lms = list(landmarks.values())
    counts = np.array([len(lm.obs_px) for lm in lms], np.int64)
    return PackedLandmarks(
        np.array(list(landmarks), np.int64),
        np.array([lm.point_world for lm in lms], np.float64).reshape(-1, 3),
        np.array([lm.colour_rgb for lm in lms], np.uint8).reshape(-1, 3),
        np.array([lm.label or (-1, -1) for lm in lms], np.int64).reshape(-1, 2),
        np.array([lm.label is not None for lm in lms], bool),
        np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
        np.fromiter((k for lm in lms for k in lm.obs_px), np.int64, int(counts.sum())),
        np.array([uv for lm in lms for uv in lm.obs_px.values()], np.float64).reshape(-1, 2))


def unpack(p: PackedLandmarks) -> dict[int, Landmark]:
    """The landmarks ``pack`` was given, equal to them (own arrays, same orders)."""
    out = {}
    kf_ids, starts = p.obs_kf_ids.tolist(), p.obs_starts.tolist()
    labels = [tuple(r) if ok else None for r, ok in zip(p.labels.tolist(), p.labelled.tolist())]
    for n, lm_id in enumerate(p.ids.tolist()):
        a, b = starts[n], starts[n + 1]
        out[lm_id] = Landmark(p.points_world[n].copy(), tuple(p.colours_rgb[n].tolist()),
                              {kf_ids[i]: p.obs_px[i].copy() for i in range(a, b)}, labels[n])
    return out


@dataclass
class SfmMap:
    """
    Keyframes and landmarks of one map segment, with id counters (ids never reused).

    ``landmarks`` is a property: a frozen map unpacks them on first access (then is not frozen).
    """

    keyframes: dict[int, MapKeyframe] = field(default_factory=dict)
    next_landmark_id: int = 0
    dirty: set[int] = field(default_factory=set)  # landmarks observed since the graph looked
    # (landmark, keyframe) of target-vertex links undone (a culled observation): a corner seen
    # again after a gap must not be tied back to a landmark through a view it was cut from.
    unlinked_vertices: set[tuple[int, int]] = field(default_factory=set)
    _landmarks: dict[int, Landmark] = field(default_factory=dict, repr=False)
    _packed: PackedLandmarks | None = field(default=None, repr=False)
    # Ids of the labelled landmarks ever added (a label is set only then; removed ones are
    # skipped when counted): ``vertex_count`` runs several times a keyframe per segment, and
    # a pass over every landmark cost ~0.7 ms at 12k landmarks.
    _labelled: set[int] = field(default_factory=set, repr=False)

    @property
    def landmarks(self) -> dict[int, Landmark]:
        if self._packed is not None:
            self._landmarks, self._packed = unpack(self._packed), None
            self._landmark_of_dtype(np.int64)
        return self._landmarks

    @property
    def frozen(self) -> bool:
        return self._packed is not None

    def freeze(self) -> None:
        """Pack the landmarks into arrays (for a segment that will not change for a while)."""
        if self._packed is None:
            self._packed, self._landmarks = pack(self._landmarks), {}
            self._landmark_of_dtype(np.int32)  # ids stay far below 2**31; values unchanged

    def _landmark_of_dtype(self, dtype: type) -> None:
        for kf in self.keyframes.values():
            kf.landmark_of = kf.landmark_of.astype(dtype)
            if kf.vertices is not None:
                kf.vertices.landmark_of = kf.vertices.landmark_of.astype(dtype)

    def landmark_count(self) -> int:
        """Number of landmarks (does not unpack a frozen map)."""
        return len(self._packed.ids) if self._packed is not None else len(self._landmarks)

    def vertex_count(self) -> int:
        """Number of target vertex (labelled) landmarks (does not unpack a frozen map)."""
        if self._packed is not None:
            return int(self._packed.labelled.sum())
        lms = self._landmarks
        self._labelled = {i for i in self._labelled if i in lms}
        return len(self._labelled)

    def add_landmark(self, point_world: FloatArray, colour_rgb: tuple[int, int, int],
                     label: tuple[int, int] | None = None) -> int:
        lm_id = self.next_landmark_id
        self.next_landmark_id += 1
        self.landmarks[lm_id] = Landmark(np.array(point_world, np.float64), colour_rgb,
                                         label=label)
        if label is not None:
            self._labelled.add(lm_id)
        return lm_id

    def observe(self, lm_id: int, kf_id: int, point_px: FloatArray, kp_index: int = -1) -> None:
        """Record that keyframe ``kf_id`` sees landmark ``lm_id`` at ``point_px`` (undistorted)."""
        # A copy: a row of a keyframe's keypoint array would keep the whole array alive.
        self.landmarks[lm_id].obs_px[kf_id] = np.array(point_px, np.float64)
        self.dirty.add(lm_id)
        if kp_index >= 0:
            self.keyframes[kf_id].landmark_of[kp_index] = lm_id

    def unobserve(self, lm_id: int, kf_id: int) -> None:
        self.landmarks[lm_id].obs_px.pop(kf_id, None)
        kf = self.keyframes[kf_id]
        if kf.vertices is not None and np.any(kf.vertices.landmark_of == lm_id):
            self.unlinked_vertices.add((lm_id, kf_id))
        for lof in (kf.landmark_of, *(() if kf.vertices is None else (kf.vertices.landmark_of,))):
            lof[lof == lm_id] = -1  # a keypoint or target vertex no longer tied to it

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
        lm_ids, kf_ids, err = self._residuals(K, kf_subset)
        return list(zip(lm_ids.tolist(), kf_ids.tolist(), err.tolist()))

    def _residuals(self, K: FloatArray, kf_subset: set[int] | None = None
                   ) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64], FloatArray]:
        """``residuals_px`` as three arrays, built without a Python loop per observation."""
        lms = self.landmarks
        if kf_subset is None:
            counts = np.fromiter((len(lm.obs_px) for lm in lms.values()), np.int64, len(lms))
            lm_ids = np.repeat(np.fromiter(lms, np.int64, len(lms)), counts)
            kf_ids = np.fromiter((k for lm in lms.values() for k in lm.obs_px), np.int64,
                                 int(counts.sum()))
            uvs = [uv for lm in lms.values() for uv in lm.obs_px.values()]
        else:  # from the keyframes' side: O(their keypoints), not O(track lengths)
            pairs = [(i, k) for k in kf_subset for i in self._seen(k)
                     if i in lms and k in lms[i].obs_px]
            lm_ids = np.array([i for i, _ in pairs], np.int64)
            kf_ids = np.array([k for _, k in pairs], np.int64)
            uvs = [lms[i].obs_px[k] for i, k in pairs]
        if not uvs:
            return lm_ids, kf_ids, np.zeros(0)
        # One pose and one point per observation, gathered by id through sorted id arrays (only
        # the keyframes observed: stacking every pose made a subset's call grow with the map).
        kf_uniq, kf_inv = np.unique(kf_ids, return_inverse=True)
        T = np.array([self.keyframes[i].T_world_cam for i in kf_uniq.tolist()])[kf_inv]
        uniq, inv = np.unique(lm_ids, return_inverse=True)
        pts = np.array([lms[i].point_world for i in uniq.tolist()]).reshape(-1, 3)[inv]
        p_cam = np.einsum('nji,nj->ni', T[:, :3, :3], pts - T[:, :3, 3])
        with np.errstate(divide='ignore', invalid='ignore'):
            uv_hat = p_cam[:, :2] / p_cam[:, 2:] @ K[:2, :2].T + K[:2, 2]
        err = np.linalg.norm(uv_hat - np.array(uvs), axis=1)
        err[~(p_cam[:, 2] > 0.0)] = np.inf
        return lm_ids, kf_ids, err

    def _seen(self, kf_id: int) -> set[int]:
        """Ids of the landmarks keyframe ``kf_id`` has a keypoint or a vertex of."""
        kf = self.keyframes[kf_id]
        ids = set(kf.landmark_of[kf.landmark_of >= 0].tolist())
        if kf.vertices is not None:
            ids.update(kf.vertices.landmark_of[kf.vertices.landmark_of >= 0].tolist())
        return ids

    def reprojection_rms_px(self, K: FloatArray, kf_subset: set[int] | None = None) -> float:
        """RMS reprojection error of all observations (or of those in ``kf_subset``), px."""
        errs = self._residuals(K, kf_subset)[2]
        return float(np.sqrt(np.mean(errs**2))) if errs.size else float('nan')

    def cull(self, K: FloatArray, max_px: float) -> int:
        """
        Drop observations with reprojection error over ``max_px`` (non-finite counts as over),
        then landmarks seen by fewer than two keyframes. Returns the landmarks removed.
        """
        lm_ids, kf_ids, err = self._residuals(K)
        bad = ~(err <= max_px)
        for lm_id, kf_id in zip(lm_ids[bad].tolist(), kf_ids[bad].tolist()):
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
