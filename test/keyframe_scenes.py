"""
Short simulator sequences with a scripted camera path for the keyframe tests.

The simulator's renderer draws the indoor scene along a path with a known pure-rotation
segment in the middle (translate, pan on the spot, translate) and one frame blurred on
purpose; the frames go into a real MCAP bag (JPEG + camera_info, as ``absscale simulate``
writes them) and the ground truth into ``BAG.gt.json`` (the subset of docs/gt_schema.md the
keyframe checks use, plus ``median_depth_m`` per frame from the renderer's depth).
"""
import json
from pathlib import Path

from absscale_ros import bagio, conversions
from absscale_ros.sim import camera as simcam
from absscale_ros.sim import render, scenes
import cv2
import numpy as np
from rclpy.serialization import serialize_message

IMAGE_TOPIC = '/camera/image_raw/compressed'
INFO_TOPIC = '/camera/camera_info'
T0_NS = 1_700_000_000_000_000_000
PERIOD_NS = 33_333_333
BLURRED_FRAME = 8


def _look_at(centre: np.ndarray, target: np.ndarray) -> np.ndarray:
    z = (target - centre) / np.linalg.norm(target - centre)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    T[:3, 3] = centre
    return T


def _rot_z(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def scripted_path(target_m: np.ndarray, n_move: int = 24, n_pan: int = 16,
                  n_back: int = 20) -> tuple[list[np.ndarray], list[tuple[int, int]]]:
    """Poses: sideways walk looking at the target, a pan on the spot, a walk forward."""
    start = target_m + np.array([-0.5, -1.8, 0.8])
    poses = [_look_at(start + [0.035 * k, 0.0, 0.0], target_m) for k in range(n_move)]
    first_pan = len(poses) - 1  # the frame that starts the rotation
    for k in range(1, n_pan + 1):
        T = poses[first_pan].copy()
        T[:3, :3] = _rot_z(np.deg2rad(1.5 * k)) @ T[:3, :3]
        poses.append(T)
    for _ in range(n_back):
        T = poses[-1].copy()
        T[:3, 3] += [0.0, 0.025, 0.0]
        poses.append(T)
    return poses, [(first_pan, first_pan + n_pan)]


def write_sequence(bag: Path, seed: int = 0, size: tuple[int, int] = (640, 360)) -> dict:
    """Render the scripted sequence of scene ``indoor_paper`` / ``seed`` into ``bag``."""
    scene = scenes.build_scene('indoor_paper', seed)
    cam = simcam.make_camera(np.random.default_rng(seed), *size)
    renderer = render.Renderer(scene, cam)
    w = scene.walk
    poses, segments = scripted_path(np.array([w['target_x'], w['target_y'], w['target_z']]))
    frames = []
    with bagio.BagWriter(bag) as writer:
        for k, T in enumerate(poses):
            view = renderer.render(T)
            image = np.clip(view.colour, 0, 255).astype(np.uint8)[..., ::-1].copy()
            blur_px = 0.0
            if k == BLURRED_FRAME:
                blur_px = 15.0  # a horizontal streak: the camera shook during the exposure
                image = cv2.filter2D(image, -1, np.full((1, 15), 1.0 / 15.0))
            stamp = T0_NS + k * PERIOD_NS
            info = conversions.camera_model_to_info_msg(cam, stamp, 'camera')
            writer.write(INFO_TOPIC, 'sensor_msgs/msg/CameraInfo', stamp, serialize_message(info))
            msg = conversions.bgr_to_compressed_msg(image, 'jpeg', 92, stamp, 'camera')
            writer.write(IMAGE_TOPIC, 'sensor_msgs/msg/CompressedImage', stamp,
                         serialize_message(msg))
            depth = view.depth_m[np.isfinite(view.depth_m)]
            frames.append({'index': k, 'stamp_ns': stamp, 'T_world_cam': T.tolist(),
                           'pure_rotation': any(a < k <= b for a, b in segments),
                           'motion_blur_px': blur_px, 'median_depth_m': float(np.median(depth))})
    gt = {'schema': 'absscale_sim_gt', 'scene': {'name': 'indoor_paper', 'seed': seed},
          'camera': {'width': cam.width, 'height': cam.height, 'K': cam.K.tolist(),
                     'distortion_model': 'plumb_bob', 'D': cam.dist.tolist()},
          'pure_rotation_segments': [list(s) for s in segments], 'frames': frames}
    Path(f'{bag}.gt.json').write_text(json.dumps(gt))
    return gt
