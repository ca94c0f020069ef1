"""
A few rendered keyframes with exact poses for the dense-cloud tests.

The simulator's renderer draws the indoor scene (640x360, the camera's lens distortion
included) from a sideways walk that looks at the calibration sheet, as a handheld scan does;
the scene's mesh is the truth the dense points are measured against.
"""
import functools

from absscale_ros.core import dense_evaluation
from absscale_ros.sim import camera as simcam
from absscale_ros.sim import render, scenes
from keyframe_scenes import _look_at
import numpy as np

STEP_M = 0.12  # between keyframes: about a tenth of the depth, as the selector spaces them


def _rendered(poses: list[np.ndarray], seed: int) -> tuple:
    scene = scenes.build_scene('indoor_paper', seed)
    cam = simcam.make_camera(np.random.default_rng(seed), 640, 360)
    renderer = render.Renderer(scene, cam)
    images = [np.clip(renderer.render(T).colour, 0, 255).astype(np.uint8)[..., ::-1].copy()
              for T in poses]
    mesh = dense_evaluation.SceneMesh(scene.vertices_m, scene.triangles)
    return images, cam, poses, mesh


def outdoor_views(poses: list[np.ndarray], seed: int = 3) -> tuple:
    """(images bgr, camera, poses, mesh) of the outdoor plaza at 1280x720 from ``poses``."""
    scene = scenes.build_scene('outdoor_cube', seed)
    cam = simcam.make_camera(np.random.default_rng(seed), 1280, 720)
    renderer = render.Renderer(scene, cam)
    images = [np.clip(renderer.render(T).colour, 0, 255).astype(np.uint8)[..., ::-1].copy()
              for T in poses]
    return images, cam, poses, dense_evaluation.SceneMesh(scene.vertices_m, scene.triangles)


def _target(seed: int) -> np.ndarray:
    w = scenes.build_scene('indoor_paper', seed).walk
    return np.array([w['target_x'], w['target_y'], w['target_z']])


@functools.lru_cache(maxsize=1)
def sideways_keyframes(count: int = 6, seed: int = 3) -> tuple:
    """(images bgr, camera, T_world_cam list, mesh) of ``count`` keyframes."""
    target = _target(seed)
    start = target + np.array([-0.4, -1.6, 0.9])
    return _rendered([_look_at(start + [STEP_M * k, 0.0, 0.0], target) for k in range(count)],
                     seed)


@functools.lru_cache(maxsize=1)
def forward_keyframes(seed: int = 3) -> tuple:
    """Two keyframes of a walk towards the sheet: 0.4 m, mostly along the optical axis."""
    target = _target(seed)
    start = target + np.array([-0.4, -1.6, 0.9])
    ahead = (target - start) / np.linalg.norm(target - start)
    side = np.cross(ahead, [0.0, 0.0, 1.0])
    step = 0.4 * (0.9 * ahead + np.sqrt(1 - 0.81) * side / np.linalg.norm(side))
    return _rendered([_look_at(start, target), _look_at(start + step, target)], seed)


@functools.lru_cache(maxsize=1)
def forward_walk(count: int = 5, seed: int = 3) -> tuple:
    """``count`` keyframes walking towards the sheet (0.12 m steps, 20 degrees off the view)."""
    target = _target(seed)
    start = target + np.array([-0.4, -1.6, 0.9])
    ahead = (target - start) / np.linalg.norm(target - start)
    side = np.cross(ahead, [0.0, 0.0, 1.0])
    step = STEP_M * (np.cos(np.radians(20)) * ahead + np.sin(np.radians(20)) * side
                     / np.linalg.norm(side))
    return _rendered([_look_at(start + k * step, target) for k in range(count)], seed)


@functools.lru_cache(maxsize=1)
def grazing_keyframes(count: int = 5, seed: int = 3) -> tuple:
    """``count`` keyframes 0.35 m above the table, looking across it (60 degrees slant)."""
    target = _target(seed)
    start = target + np.array([-0.2, -0.7, 0.35])
    return _rendered([_look_at(start + [0.08 * k, 0.0, 0.0], target + [0.0, -0.1, 0.0])
                      for k in range(count)], seed)


def _pose(rows: list[list[float]]) -> np.ndarray:
    """A 4x4 T_world_cam from 3x4 rows rounded to 4 digits (rotation made orthonormal again)."""
    T = np.eye(4)
    T[:3] = rows
    U, _, Vt = np.linalg.svd(T[:3, :3])
    T[:3, :3] = U @ Vt
    return T


@functools.lru_cache(maxsize=1)
def wide_near_pair() -> tuple:
    """Two keyframes of indoor seed 64's walk (its 15th and 10th, true poses) 0.8 m apart,
    0.35 m of it backwards, 1-4 m from the desk: disparities of 100-460 px at 640 px."""
    return _rendered([_pose([[0.6398, -0.4609, 0.615, 2.8156], [-0.768, -0.413, 0.4895, 4.5358],
                             [0.0284, -0.7855, -0.6182, 1.5707]]),
                      _pose([[0.8904, -0.1844, 0.4161, 2.9281], [-0.4542, -0.4187, 0.7864, 3.7235],
                             [0.0292, -0.8892, -0.4565, 1.6083]])], 64)
