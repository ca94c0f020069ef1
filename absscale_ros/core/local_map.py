"""
Guided search of the local map (covisibility registration).

Feature matching links a new keyframe only to the few newest keyframes. Once its pose is known,
the landmarks seen by a wider window of recent keyframes are projected into it and matched by
descriptor near their predicted position, so tracks get longer and keyframes further apart are
tied together directly: on fast stretches with few shared points per pair, short tracks let
the map's scale drift.
"""
from dataclasses import dataclass
from itertools import chain

import numpy as np
import numpy.typing as npt

from absscale_ros.core import sfm_map, twoview

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class LocalMapConfig:
    """Window and acceptance of the guided search."""

    keyframes: int = 10  # landmarks of this many newest keyframes are looked for (0: off)
    radius_px: float = 4.0  # a keypoint this close to a landmark's projection is a candidate
    ratio: float = 0.8  # best descriptor distance under this share of the second best
    max_distance: float = 200.0  # ... and under this (SIFT L2, 90 % of verified matches)
    # Before the final batch, each keyframe still holding descriptors looks for the landmarks
    # of this many neighbours on each side, the newer ones included (0: off).
    final_keyframes: int = 10
    final_radius_px: float = 2.0  # ... within this of its projection, px (the poses have settled)

    def __post_init__(self) -> None:
        if min(self.keyframes, self.final_keyframes) < 0 or not 0.0 < self.ratio <= 1.0 or \
                min(self.radius_px, self.final_radius_px, self.max_distance) <= 0.0:
            raise ValueError(f'bad local map config {self}')


def _landmark_descriptors(m: sfm_map.SfmMap, recent: list[sfm_map.MapKeyframe],
                          skip: npt.NDArray[np.int64]) -> tuple[npt.NDArray[np.int64], FloatArray]:
    """Landmarks seen by ``recent`` (newest first) minus ``skip``; each with its newest
    descriptor. Vectorised: the window holds ~10k observations, a Python loop cost ~10 ms."""
    rows = [np.flatnonzero(kf.landmark_of >= 0) for kf in recent]
    if not sum(len(r) for r in rows):
        return np.zeros(0, np.int64), np.zeros((0, 128), np.float32)
    lms = np.concatenate([kf.landmark_of[r] for kf, r in zip(recent, rows)]).astype(np.int64)
    ids, first = np.unique(lms, return_index=True)  # first: in the newest keyframe seeing it
    keep = ~np.isin(ids, skip) & np.fromiter(map(m.landmarks.__contains__, ids.tolist()),
                                             bool, len(ids))
    first = np.sort(first[keep])  # newest keyframe first, as the loop over ``recent`` went
    descs = np.concatenate([kf.features.descriptors[r] for kf, r in zip(recent, rows)])
    return lms[first], descs[first]


def search(m: sfm_map.SfmMap, K: FloatArray, kf: sfm_map.MapKeyframe, size: tuple[int, int],
           cfg: LocalMapConfig, others: list[sfm_map.MapKeyframe] | None = None) -> int:
    """
    Add observations of local-map landmarks to the registered keyframe ``kf`` (in ``m``).

    :param size: image (width, height), px.
    :param others: the keyframes whose landmarks are looked for, newest first (None: the
        ``cfg.keyframes`` newest of the map); each must still hold its descriptors.
    :returns: observations added.
    """
    recent = [m.keyframes[i] for i in sorted(m.keyframes, reverse=True)
              if i != kf.kf_id][:cfg.keyframes] if others is None else others
    free = np.flatnonzero(kf.landmark_of < 0)
    if not recent or not len(free) or kf.features.descriptors.dtype != np.float32:  # SIFT only
        return 0
    lm_ids, descs = _landmark_descriptors(m, recent, kf.landmark_of[kf.landmark_of >= 0])
    if not len(lm_ids):
        return 0
    landmarks = m.landmarks
    uv = twoview.project(K, kf.T_world_cam, np.array([landmarks[i].point_world
                                                      for i in lm_ids.tolist()]))
    inside = np.all(np.isfinite(uv), axis=1) & (uv[:, 0] >= 0) & (uv[:, 1] >= 0) & \
        (uv[:, 0] < size[0]) & (uv[:, 1] < size[1])
    cand = np.flatnonzero(inside)
    from scipy.spatial import cKDTree  # here: scipy.spatial is 0.3-0.6 s of a process's start
    near = cKDTree(kf.features.points_px[free]).query_ball_point(uv[cand], cfg.radius_px)
    counts = np.fromiter(map(len, near), np.int64, len(near))
    total = int(counts.sum())
    if not total:
        return 0
    li = np.repeat(cand, counts)  # (landmark row, free keypoint) candidate pairs
    kj = free[np.fromiter(chain.from_iterable(near), np.int64, total)]
    dist = np.linalg.norm(descs[li].astype(np.float32) -
                          kf.features.descriptors[kj].astype(np.float32), axis=1)
    order = np.lexsort((dist, li))
    li, kj, dist = li[order], kj[order], dist[order]
    first = np.flatnonzero(np.r_[True, li[1:] != li[:-1]])
    second = np.where(first + 1 < len(li), first + 1, first)
    has_second = (second != first) & (li[second] == li[first])
    ok = (dist[first] < cfg.max_distance) & \
        (~has_second | (dist[first] < cfg.ratio * dist[second]))
    best = first[ok]
    best = best[np.argsort(dist[best], kind='stable')]  # a keypoint goes to its closest landmark
    _, keep = np.unique(kj[best], return_index=True)
    for b in best[keep]:
        m.observe(int(lm_ids[li[b]]), kf.kf_id, kf.features.points_px[kj[b]], int(kj[b]))
    return len(keep)
