"""
Ground truth of a simulated bag: per-frame truth, the gt.json schema check, and the 3D point
behind any pixel (re-rendered from scene name + seed + variant). Schema: docs/gt_schema.md.
"""
import functools
import json
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core.types import CameraModel
from absscale_ros.sim import camera as simcam
from absscale_ros.sim import scenes
from absscale_ros.sim.scene import FloatArray, Scene, Target

if TYPE_CHECKING:  # render loads Open3D (~3 s): not for reading a gt.json (absscale run's end)
    from absscale_ros.sim import render

SCHEMA = 'absscale_sim_gt'
SCHEMA_VERSION = 1
MIN_AREA_FRACTION = 0.005  # the paper's minimum target area (share of the image)
POLYGON_EPSILON_PX = 0.7


def target_json(target: Target, tid: int) -> dict[str, object]:
    """The ``targets[i]`` entry of gt.json."""
    return {'id': tid, 'kind': target.kind, 'name': target.name, 'size_m': list(target.size_m),
            'vertices_world_m': target.vertices_world_m.tolist(),
            'edges': [list(e) for e in target.edges],
            'faces': [{'id': i, 'vertex_ids': list(f), 'colour': c}
                      for i, (f, c) in enumerate(zip(target.faces, target.colours))]}


def camera_json(camera: CameraModel) -> dict[str, object]:
    """The ``camera`` entry of gt.json."""
    return {'width': camera.width, 'height': camera.height, 'K': camera.K.tolist(),
            'distortion_model': camera.distortion_model, 'D': camera.dist.tolist(),
            'hfov_deg': float(np.rad2deg(2.0 * np.arctan2(camera.width / 2, camera.K[0, 0])))}


def camera_from_json(cam: dict[str, object]) -> CameraModel:
    """Inverse of ``camera_json``."""
    return CameraModel(int(cam['width']), int(cam['height']), np.array(cam['K']),  # type: ignore
                       np.array(cam['D']), str(cam['distortion_model']))


def vertex_visibility(renderer: 'render.Renderer', T_world_cam: FloatArray,
                      vertices_world_m: FloatArray) -> tuple[FloatArray, list[bool]]:
    """
    Distorted pixel positions and visibility of world points.

    A vertex is visible when in front of the camera, inside the image, and the first ray hit
    towards it is no nearer than the vertex itself (1 cm + 0.1 % tolerance: it lies on a face).

    :returns: (V, 2) positions, px (NaN behind the camera); per vertex visibility.
    """
    cam = renderer.camera
    R, t = T_world_cam[:3, :3], T_world_cam[:3, 3]
    pts_cam = (vertices_world_m - t) @ R
    uv = simcam.project(cam, pts_cam)
    dist = np.linalg.norm(pts_cam, axis=1)
    hit_t, _ = renderer.cast(T_world_cam, (pts_cam / dist[:, None]).astype(np.float32))
    inside = ((uv[:, 0] >= -0.5) & (uv[:, 0] <= cam.width - 0.5)
              & (uv[:, 1] >= -0.5) & (uv[:, 1] <= cam.height - 0.5))
    unhidden = hit_t >= dist - (0.01 + 0.001 * dist)
    visible = (pts_cam[:, 2] > 0) & inside & unhidden
    return uv, [bool(v) for v in visible]


def face_outline(surface: npt.NDArray[np.int32], surface_id: int,
                 roi: tuple[int, int, int, int]) -> dict[str, object] | None:
    """
    Outline of the pixels whose centre ray hits ``surface_id``, inside ``roi`` (x0 y0 x1 y1).

    :returns: ``{area_px, polygons_px, holes_px}`` or None when no pixel hits the face.
    """
    x0, y0, x1, y1 = roi
    mask = (surface[y0:y1, x0:x1] == surface_id).astype(np.uint8)
    area = int(cv2.countNonZero(mask))
    if area == 0:
        return None
    contours, hierarchy = cv2.findContours(mask, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_SIMPLE,
                                           offset=(x0, y0))
    outer, holes = [], []
    for c, h in zip(contours, hierarchy[0]):
        ring = cv2.approxPolyDP(c, POLYGON_EPSILON_PX, True).reshape(-1, 2).tolist()
        (holes if h[3] >= 0 else outer).append(ring)
    return {'area_px': area, 'polygons_px': outer, 'holes_px': holes}


def frame_targets(renderer: 'render.Renderer', frame: 'render.Frame', T_world_cam: FloatArray,
                  visibility: list[tuple[FloatArray, list[bool]]] | None = None
                  ) -> list[dict[str, object]]:
    """
    ``frames[k].targets``: vertices, visibility, face outlines, area of every target.

    :param visibility: per target the result of ``vertex_visibility`` if already known.
    """
    scene = renderer.scene
    cam = renderer.camera
    out = []
    for tid, target in enumerate(scene.targets):
        uv, visible = (visibility[tid] if visibility is not None else
                       vertex_visibility(renderer, T_world_cam, target.vertices_world_m))
        finite = uv[np.isfinite(uv).all(axis=1)]
        if len(finite) == len(uv):  # all in front: the outline lies within their hull
            lo = np.clip(np.floor(finite.min(axis=0)) - 2, 0, [cam.width, cam.height]).astype(int)
            hi = np.clip(np.ceil(finite.max(axis=0)) + 3, 0, [cam.width, cam.height]).astype(int)
            roi = (int(lo[0]), int(lo[1]), int(hi[0]), int(hi[1]))
        else:
            roi = (0, 0, cam.width, cam.height)
        faces, area = [], 0
        if roi[2] > roi[0] and roi[3] > roi[1]:
            for fid in range(len(target.faces)):
                sid = int(np.flatnonzero((scene.surface_target == tid)
                                         & (scene.surface_face == fid))[0])
                outline = face_outline(frame.surface, sid, roi)
                if outline is not None:
                    faces.append({'id': fid, **outline})
                    area += int(outline['area_px'])  # type: ignore[call-overload]
        fraction = area / float(cam.width * cam.height)
        out.append({'id': tid,
                    'vertices_px': [None if not np.isfinite(p).all() else [round(float(p[0]), 5),
                                    round(float(p[1]), 5)] for p in uv],
                    'vertex_visible': visible, 'area_fraction': round(fraction, 7),
                    'covers_min_area': fraction >= MIN_AREA_FRACTION, 'faces': faces})
    return out


def save(gt: dict[str, object], path: str | Path) -> None:
    """Validate and write gt.json (compact: one frame per line)."""
    validate(gt)
    frames = gt['frames']
    head = {k: v for k, v in gt.items() if k != 'frames'}
    text = json.dumps(head, indent=1, allow_nan=False)[:-2]
    lines = ',\n'.join(json.dumps(f, separators=(',', ':'), allow_nan=False)
                       for f in frames)  # type: ignore[attr-defined]
    Path(path).write_text(text + ',\n "frames": [\n' + lines + '\n]}\n')


def load(path: str | Path) -> dict[str, object]:
    """Read and validate a gt.json."""
    gt = json.loads(Path(path).read_text())
    validate(gt)
    return gt  # type: ignore[no-any-return]


def _need(cond: bool, what: str) -> None:
    if not cond:
        raise ValueError(f'gt.json: {what}')


def validate(gt: dict[str, object]) -> None:
    """
    Check ``gt`` against docs/gt_schema.md (version 1).

    :raises ValueError: naming the first deviation.
    """
    _need(gt.get('schema') == SCHEMA and gt.get('schema_version') == SCHEMA_VERSION,
          'schema tag / version')
    for key in ('sim_version', 'scene', 'bag', 'camera', 'light', 'targets', 'distractors',
                'point_pairs', 'pure_rotation_segments', 'frames'):
        _need(key in gt, f'missing {key!r}')
    cam = gt['camera']
    _need(np.array(cam['K']).shape == (3, 3)  # type: ignore[index]
          and len(cam['D']) == 5, 'camera K / D')  # type: ignore[index]
    w, h = cam['width'], cam['height']  # type: ignore[index]
    targets = gt['targets']
    nverts = [len(t['vertices_world_m']) for t in targets]  # type: ignore[attr-defined,index]
    for t in targets:  # type: ignore[attr-defined]
        _need(t['kind'] in ('sheet', 'cube'), f'target kind {t["kind"]!r}')
        _need(len(t['edges']) == (4 if t['kind'] == 'sheet' else 12), 'target edges')
    for p in gt['point_pairs']:  # type: ignore[attr-defined]
        d = np.linalg.norm(np.subtract(p['a_world_m'], p['b_world_m']))
        _need(abs(d - p['distance_m']) < 1e-9, f'point pair {p["label"]!r} distance')
    frames = gt['frames']
    _need(len(frames) == gt['bag']['frame_count'], 'frame_count')  # type: ignore
    for seg in gt['pure_rotation_segments']:  # type: ignore[attr-defined]
        _need(0 <= seg[0] <= seg[1] < len(frames), f'rotation segment {seg}')  # type: ignore
    for k, f in enumerate(frames):  # type: ignore[arg-type]
        _need(f['index'] == k, f'frame {k} index')
        T = np.array(f['T_world_cam'])
        _need(T.shape == (4, 4) and np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-9)
              and np.allclose(T[3], [0, 0, 0, 1]), f'frame {k} pose')
        _need(len(f['targets']) == len(targets), f'frame {k} targets')
        for ft, nv in zip(f['targets'], nverts):
            _need(len(ft['vertices_px']) == nv and len(ft['vertex_visible']) == nv,
                  f'frame {k} target {ft["id"]} vertices')
            for p, vis in zip(ft['vertices_px'], ft['vertex_visible']):
                _need(not vis or (p is not None and -0.5 <= p[0] <= w - 0.5
                                  and -0.5 <= p[1] <= h - 0.5), f'frame {k} visible vertex')
            _need(ft['covers_min_area'] == (ft['area_fraction'] >= MIN_AREA_FRACTION),
                  f'frame {k} covers_min_area')
            for face in ft['faces']:
                _need(face['area_px'] > 0 and len(face['polygons_px']) > 0, f'frame {k} face')


@functools.lru_cache(maxsize=2)
def _renderer(scene_key: str, camera_key: str) -> 'render.Renderer':
    from absscale_ros.sim import render
    sc = json.loads(scene_key)
    scene: Scene = scenes.build_scene(sc['name'], sc['seed'], sc['variant'])
    return render.Renderer(scene, camera_from_json(json.loads(camera_key)))


def renderer_for(gt: dict[str, object]) -> 'render.Renderer':
    """The renderer of the bag's scene and camera (rebuilt from name + seed + variant)."""
    _need(gt.get('sim_version') == scenes.SIM_VERSION,
          f'sim_version {gt.get("sim_version")} != this renderer {scenes.SIM_VERSION}')
    return _renderer(json.dumps(gt['scene'], sort_keys=True),
                     json.dumps(gt['camera'], sort_keys=True))


def points_behind_pixels(gt: dict[str, object], frame_index: int,
                         pixels_px: npt.ArrayLike) -> FloatArray:
    """
    True world points seen at distorted pixel positions of a frame.

    :param pixels_px: (N, 2) positions (u, v), px, pixel centres at integers.
    :returns: (N, 3) world points, m; NaN rows where the ray sees the sky.
    """
    r = renderer_for(gt)
    T = np.array(gt['frames'][frame_index]['T_world_cam'])  # type: ignore[index]
    dirs = simcam.ray_directions(r.camera, np.asarray(pixels_px, float).reshape(-1, 2))
    t, _ = r.cast(T, dirs)
    hit = np.isfinite(t)
    pts = np.full((len(t), 3), np.nan)
    pts[hit] = T[:3, 3] + (dirs[hit].astype(np.float64) * t[hit, None]) @ T[:3, :3].T
    return pts


def depth_map(gt: dict[str, object], frame_index: int) -> npt.NDArray[np.float32]:
    """(H, W) z-depth in the camera frame of every pixel of a frame, m; NaN for sky."""
    r = renderer_for(gt)
    T = np.array(gt['frames'][frame_index]['T_world_cam'])  # type: ignore[index]
    z, _ = r.depth(T)
    return np.where(np.isfinite(z), z, np.nan).astype(np.float32)
