"""
Short rendered handheld sequences for the SfM tests and bench (simulator scenes, no bag).

Until ``absscale simulate`` writes bags with keyframes, the tests render keyframes straight from
``absscale_ros.sim`` along an orbit around the target, and take the ground-truth 2D vertices
(plus Gaussian pixel noise) as the "detected" vertices.
"""
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from absscale_ros.core.types import CameraModel
from absscale_ros.sim import camera as simcam
from absscale_ros.sim import render, scenes

FloatArray = npt.NDArray[np.float64]


@dataclass
class Sequence:
    """Keyframe images (BGR uint8), poses T_world_cam (K, 4, 4) and the target's vertices."""

    camera: CameraModel
    images_bgr: list[npt.NDArray[np.uint8]]
    T_world_cams: FloatArray
    vertices_world_m: FloatArray  # (V, 3)
    vertices_px: list[FloatArray]  # per keyframe (V, 2) distorted px, NaN where not visible
    kind: str  # 'sheet' or 'cube'


def look_at(eye_m: FloatArray, target_m: FloatArray) -> FloatArray:
    """T_world_cam of an optical-frame camera at ``eye_m`` looking at ``target_m`` (z up)."""
    z = target_m - eye_m
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, y, z])
    T[:3, 3] = eye_m
    return T


def orbit_poses(scene_name: str, walk: dict[str, float], count: int, arc_rad: float,
                rng: np.random.Generator, rotate_only: bool = False) -> FloatArray:
    """Poses on an arc around the target (or a pan from one spot), with a little hand shake."""
    centre = np.array([walk['target_x'], walk['target_y'], walk['target_z']])
    radius, height = (1.1, 0.6) if scene_name == 'indoor_paper' else (6.0, 1.2)
    # Indoors the camera stays on the approach side of the desk; outdoors any side is open.
    side = 0.0 if scene_name == 'indoor_paper' else np.pi
    start = walk['approach_rad'] + side - 0.5 * arc_rad
    poses = []
    for k in range(count):
        a = start + arc_rad * k / max(count - 1, 1)
        if rotate_only:
            a0 = start + 0.5 * arc_rad
            eye = centre + np.array([radius * np.cos(a0), radius * np.sin(a0), height])
            look = eye + np.array([-np.cos(a), -np.sin(a), -height / radius])
        else:
            eye = centre + np.array([radius * np.cos(a), radius * np.sin(a), height])
            eye += rng.normal(0.0, 0.01 * radius, 3)
            look = centre + rng.normal(0.0, 0.05 * radius, 3)
        poses.append(look_at(eye, look))
    return np.array(poses)


def make_sequence(scene_name: str, seed: int, count: int = 12, width: int = 640,
                  arc_deg: float = 40.0, noise_px: float = 0.3,
                  rotate_only: bool = False) -> Sequence:
    """Render ``count`` keyframes of scene ``scene_name`` / ``seed`` at ``width`` px."""
    scene = scenes.build_scene(scene_name, seed)
    rng = scenes.streams(seed)['trajectory']
    camera = simcam.make_camera(scenes.streams(seed)['camera'], width, width * 9 // 16)
    renderer = render.Renderer(scene, camera)
    poses = orbit_poses(scene_name, scene.walk, count, np.deg2rad(arc_deg), rng, rotate_only)
    target = scene.targets[0]
    images, vertices = [], []
    for T in poses:
        colour = renderer.render(T).colour
        # The renderer's colour scale moved from [0, 1.2] to 8-bit while it is being written.
        gain = 255.0 if float(colour.max()) <= 2.0 else 1.0
        rgb = np.clip(colour * gain + 0.5, 0.0, 255.0).astype(np.uint8)
        images.append(np.ascontiguousarray(rgb[..., ::-1]))
        p_cam = (target.vertices_world_m - T[:3, 3]) @ T[:3, :3]
        px = simcam.project(camera, p_cam) + rng.normal(0.0, noise_px, (len(p_cam), 2))
        inside = (p_cam[:, 2] > 0) & (px[:, 0] >= 0) & (px[:, 0] < camera.width) & \
            (px[:, 1] >= 0) & (px[:, 1] < camera.height)
        px[~inside] = np.nan
        vertices.append(px)
    return Sequence(camera, images, poses, target.vertices_world_m.copy(), vertices, target.kind)


def detections(seq: Sequence, k: int, rng: np.random.Generator) -> tuple[object, FloatArray]:
    """
    Stand-in for the vertex detector on keyframe ``k``: the visible ground-truth vertices, with
    the detector's per-frame numbering (a sheet's clockwise order from a random corner, the cube's
    vertices in random order), so identities across keyframes must come from matching.

    :returns: ``vertex_matching.Vertices`` (distorted px) and (V,) true vertex index of each.
    """
    from absscale_ros.core import vertex_matching as vm
    px = seq.vertices_px[k]
    visible = np.flatnonzero(np.all(np.isfinite(px), axis=1))
    if seq.kind == 'cube':  # the vertex furthest from the camera is hidden by the cube itself
        dist_m = np.linalg.norm(seq.vertices_world_m - seq.T_world_cams[k, :3, 3], axis=1)
        visible = visible[visible != int(np.argmax(dist_m))]
    if seq.kind == 'sheet':
        if len(visible) < 4:
            visible = visible[:0]
        order = np.roll(np.arange(len(visible)), int(rng.integers(4))) if len(visible) else visible
    else:
        order = rng.permutation(len(visible))
    true_ids = visible[order]
    n = len(true_ids)
    return (vm.Vertices(np.zeros(n, np.int64), np.arange(n, dtype=np.int64), px[true_ids],
                        (seq.kind,) * n), true_ids)
