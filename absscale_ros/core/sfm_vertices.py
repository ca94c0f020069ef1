"""
Target vertices as labelled landmarks of an SfM map segment (paper Steps 2-3).

After a keyframe is registered its detected vertices are matched (``vertex_matching``) with
those of the previous keyframes; a match extends a vertex landmark or, once two views see the
vertex with enough parallax, creates one labelled (object_id, vertex_id) from the first view.

A match is only a candidate: the cube's corners, 30 px apart from 15 m, can pass the epipolar
and colour test for a neighbour (the live 60 s bag, which skips keyframes: corner 1 took corner
5's observations, the landmark settled 0.67 m off with 2 px residuals and bent the map). So a
landmark extends to a new keyframe only where it projects nearer the matched vertex than to any
other, and two landmarks seen in one keyframe are never merged. A corner back in view after
more keyframes than the match window is tied to the landmark it already has where that projects
onto it unambiguously in both views, instead of starting a second, few-view landmark.
"""
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from absscale_ros.core import sfm_map, twoview
from absscale_ros.core import vertex_matching as vm

FloatArray = npt.NDArray[np.float64]


@dataclass
class KeyframeVertices:
    """Vertices of one keyframe, their colour windows and the landmark each became (-1: none)."""

    vertices: vm.Vertices
    windows: list[FloatArray | None]
    landmark_of: npt.NDArray[np.int64]


def make(vertices: vm.Vertices, image_bgr: npt.NDArray[np.uint8],
         cfg: vm.VertexMatchConfig) -> KeyframeVertices:
    return KeyframeVertices(vertices, vm.windows(image_bgr, vertices.points_px, cfg),
                            np.full(len(vertices.object_ids), -1, np.int64))


def _pairs(a: KeyframeVertices, b: KeyframeVertices, F: FloatArray,
           cfg: vm.VertexMatchConfig) -> list[tuple[int, int]]:
    """Matches per target kind; objects are matched by id only if the detector keeps ids."""
    out = []
    for kind in ('sheet', 'cube'):
        ia = [i for i, k in enumerate(a.vertices.kinds) if k == kind]
        ib = [j for j, k in enumerate(b.vertices.kinds) if k == kind]
        if not ia or not ib:
            continue
        for obj in set(a.vertices.object_ids[ia].tolist()):
            sa = [i for i in ia if a.vertices.object_ids[i] == obj]
            sb = [j for j in ib if b.vertices.object_ids[j] == obj]
            pa, pb = a.vertices.points_px[sa], b.vertices.points_px[sb]
            if kind == 'sheet':
                local = vm.match_sheet(pa, pb, F, cfg)
            else:
                local = vm.match_cube(pa, pb, [a.windows[i] for i in sa],
                                      [b.windows[j] for j in sb], F, cfg)
            out += [(sa[i], sb[j]) for i, j in local]
    return out


def link(m: sfm_map.SfmMap, K: FloatArray, new: sfm_map.MapKeyframe,
         older: list[sfm_map.MapKeyframe], tv_cfg: twoview.TwoViewConfig,
         cfg: vm.VertexMatchConfig) -> int:
    """
    Match ``new``'s vertices with those of ``older`` keyframes; add observations and landmarks.

    :returns: number of vertex landmarks created.
    """
    b = new.vertices
    if b is None:
        return 0
    created, labelled = 0, None
    for old in older:
        a = old.vertices
        if a is None:
            continue
        F = vm.fundamental(K, old.T_world_cam, new.T_world_cam)
        for i, j in _pairs(a, b, F, cfg):
            if a.landmark_of[i] >= 0 and not _projects_to(m, K, int(a.landmark_of[i]), new, j):
                continue  # a neighbouring corner matched: not this landmark
            if b.landmark_of[j] >= 0:
                if a.landmark_of[i] >= 0 and a.landmark_of[i] != b.landmark_of[j]:
                    merge(m, int(b.landmark_of[j]), int(a.landmark_of[i]))
                continue
            if a.landmark_of[i] >= 0:
                b.landmark_of[j] = a.landmark_of[i]
                m.observe(int(a.landmark_of[i]), new.kf_id, b.vertices.points_px[j])
                continue
            if labelled is None:  # once per call: the map's scan grew with it (~6 ms)
                labelled = [k for k, lm in m.landmarks.items() if lm.label is not None]
            lm_id = _coinciding(m, K, old, i, new, j, labelled)
            if lm_id >= 0:  # a corner seen again after a gap: the landmark it already has
                for kf, v, k in ((old, a, i), (new, b, j)):
                    v.landmark_of[k] = lm_id
                    m.observe(lm_id, kf.kf_id, v.vertices.points_px[k])
                continue
            pts, ok = twoview.triangulate(K, old.T_world_cam, new.T_world_cam,
                                          a.vertices.points_px[i:i + 1],
                                          b.vertices.points_px[j:j + 1], tv_cfg)
            if not ok[0]:
                continue
            label = (int(a.vertices.object_ids[i]), int(a.vertices.vertex_ids[i]))
            lm_id = m.add_landmark(pts[0], (255, 255, 255), label)
            m.observe(lm_id, old.kf_id, a.vertices.points_px[i])
            m.observe(lm_id, new.kf_id, b.vertices.points_px[j])
            a.landmark_of[i] = b.landmark_of[j] = lm_id
            created += 1
            if labelled is not None:
                labelled.append(lm_id)
    return created


def _projects_to(m: sfm_map.SfmMap, K: FloatArray, lm_id: int, kf: sfm_map.MapKeyframe,
                 j: int) -> bool:
    """Whether landmark ``lm_id`` projects into ``kf`` nearer its vertex ``j`` than a third of
    the way to any other of its vertices (in front of the camera)."""
    T = kf.T_world_cam
    p_cam = T[:3, :3].T @ (m.landmarks[lm_id].point_world - T[:3, 3])
    if p_cam[2] <= 0.0:
        return False
    uv = (K @ p_cam)[:2] / p_cam[2]
    pts = kf.vertices.vertices.points_px
    gaps = np.linalg.norm(np.delete(pts, j, axis=0) - pts[j], axis=1)
    return bool(np.linalg.norm(uv - pts[j]) < (gaps.min() / 3.0 if len(gaps) else np.inf))


def _coinciding(m: sfm_map.SfmMap, K: FloatArray, a: sfm_map.MapKeyframe, i: int,
                b: sfm_map.MapKeyframe, j: int, labelled: list[int]) -> int:
    """
    The vertex landmark of the same object that vertex ``i`` of ``a`` and ``j`` of ``b`` see
    again (-1: none): in both keyframes the landmark of that object projecting nearest the
    vertex, by less than half the way to the next one, and ``_projects_to`` it; not observed
    in either yet, nor cut from either (``SfmMap.unlinked_vertices``). A corner out of view for
    longer than the match window would otherwise become a second landmark, triangulated from a
    few recent views only. ``labelled``: the ids of the map's vertex landmarks, in its order
    (some may have been merged away since).
    """
    obj = int(a.vertices.vertices.object_ids[i])
    ids = [k for k in labelled if k in m.landmarks and m.landmarks[k].label[0] == obj]
    found = -1
    points = np.array([m.landmarks[k].point_world for k in ids]).reshape(-1, 3)
    for kf, n in ((a, i), (b, j)):
        # Behind the camera: inf, so never nearest nor the runner-up that makes it ambiguous.
        d = np.linalg.norm(twoview.project(K, kf.T_world_cam, points)
                           - kf.vertices.vertices.points_px[n], axis=1)
        if not np.isfinite(d).any():
            return -1
        order = np.argsort(d)
        best = ids[int(order[0])]
        if (len(d) > 1 and d[order[0]] >= 0.5 * d[order[1]]) or found not in (-1, best) or \
                not _projects_to(m, K, best, kf, n) or kf.kf_id in m.landmarks[best].obs_px or \
                (best, kf.kf_id) in m.unlinked_vertices:
            return -1
        found = best
    return found


def merge(m: sfm_map.SfmMap, keep: int, drop: int) -> None:
    """
    Make vertex landmark ``drop`` part of ``keep`` (one physical vertex reached along two
    chains of matches): its observations move over unless ``keep`` has one in that keyframe.
    """
    if keep not in m.landmarks or drop not in m.landmarks:
        return
    kept = m.landmarks[keep]
    if kept.obs_px.keys() & m.landmarks[drop].obs_px.keys():
        return  # two vertices of one image: two corners, whatever matched them
    for kf_id, uv in m.landmarks[drop].obs_px.items():
        if kf_id not in kept.obs_px:
            m.observe(keep, kf_id, uv)  # marks it for the graph
    for kf in m.keyframes.values():
        if kf.vertices is not None:
            lof = kf.vertices.landmark_of
            lof[lof == drop] = keep
    m.landmarks[drop].obs_px.clear()  # vertex observations have no keypoint index to clear
    del m.landmarks[drop]


def targets(m: sfm_map.SfmMap) -> tuple[FloatArray, npt.NDArray[np.int64]]:
    """
    Vertex landmarks, sorted by object and vertex id.

    :returns: (N, 3) positions (SfM units) and (N, 3) int64 rows of object_id, vertex_id and
        observation count.
    """
    rows = sorted(((lm.label, lm.point_world, len(lm.obs_px)) for lm in m.landmarks.values()
                   if lm.label is not None), key=lambda r: r[0])
    pts = np.array([r[1] for r in rows], np.float64).reshape(-1, 3)
    ids = np.array([[r[0][0], r[0][1], r[2]] for r in rows], np.int64).reshape(-1, 3)
    return pts, ids
