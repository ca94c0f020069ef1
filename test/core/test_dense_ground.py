"""Ground fill (dense_ground) on rendered views of the outdoor plaza, against the scene mesh."""
import functools

from absscale_ros.core import dense_facade, dense_ground, dense_stereo, dense_sweep
import dense_scenes
from keyframe_scenes import _look_at
import numpy as np

SWEEP = dense_sweep.SweepConfig()
GROUND = dense_ground.GroundConfig(enabled=True)
EYE_M = 1.6  # camera height over the plaza


@functools.lru_cache(maxsize=1)
def _ground_views() -> tuple:
    """Three 1280x720 views along the plaza's ground (objects on it 5-25 m away), 2 m apart."""
    eye, ahead = np.array([-4.0, -14.0, EYE_M]), np.array([4.0, 14.0, 0.0])
    side = np.cross(ahead - eye, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    return dense_scenes.outdoor_views([_look_at(eye + k * side, ahead + k * side)
                                       for k in (-2.0, 0.0, 2.0)])


def _plane(T_world_cam: np.ndarray, height_m: float = 0.0) -> np.ndarray:
    """The horizontal plane at ``height_m`` as ``p`` (p . X = 1) in the camera."""
    n = -T_world_cam[:3, :3].T @ np.array([0.0, 0.0, 1.0])  # towards the ground, camera frame
    return n / (T_world_cam[2, 3] - height_m)


def _filled(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The middle view's ground fill with plane ``p``: its depth (sweep view) and K."""
    images, cam, poses, _ = _ground_views()
    small, small_cam = dense_stereo.working_image(images[1], cam, dense_stereo.StereoConfig())
    _, grey, K = dense_sweep.pinhole_view(small, small_cam, SWEEP)
    views = [(dense_facade.fine_view(images[k], cam)[0].astype(np.float32),
              dense_stereo.relative_pose(poses[1], poses[k])) for k in (0, 2)]
    ref, K_fine = dense_facade.fine_view(images[1], cam)
    blocked = np.zeros(grey.shape, bool)
    z = dense_ground.candidates(p, K, blocked, GROUND)
    return dense_ground.fill(grey, (ref.astype(np.float32), views, K_fine), K, z, p, GROUND), K


def test_the_ground_is_filled_far_beyond_stereo_within_centimetres() -> None:
    _, _, poses, mesh = _ground_views()
    depth, K = _filled(_plane(poses[1]))
    pts, _, _ = dense_stereo.back_project(depth, K)
    world = pts @ poses[1][:3, :3].T + poses[1][:3, 3]
    far = pts[:, 2] > 12.0
    assert far.sum() > 2000  # beyond where the pairs reach on the plaza
    error = mesh.distance(world)
    assert np.percentile(error, 90) < 0.05
    assert np.mean(error[far] < 0.05) > 0.9


def test_a_plane_off_the_ground_is_refused_by_the_views() -> None:
    # 15 cm above the plaza: the warped views no longer agree with the keyframe, so the
    # check (not the candidates, which a raised plane has as many of) keeps few pixels.
    _, _, poses, _ = _ground_views()
    right = np.count_nonzero(_filled(_plane(poses[1]))[0])
    raised = np.count_nonzero(_filled(_plane(poses[1], 0.15))[0])
    assert raised < 0.3 * right


def test_the_ground_plane_is_the_near_ground_and_a_wall_ahead_is_none() -> None:
    _, _, poses, _ = _ground_views()
    rng = np.random.default_rng(0)
    x, z = rng.uniform(-4.0, 4.0, 4000), rng.uniform(2.0, 11.0, 4000)
    truth = _plane(poses[1])
    # points on the true ground under the middle view, 3 mm of noise along the rays
    rays = np.stack([x / z, np.zeros_like(x), np.ones_like(x)], 1)
    rays[:, 1] = (1.0 / z - truth[0] * rays[:, 0] - truth[2]) / truth[1]  # p . (z ray) = 1
    pts = rays * (z * (1.0 + rng.normal(0.0, 0.003, len(x))))[:, None]
    pts = pts[np.linalg.norm(pts, axis=1) < GROUND.max_range_m]
    p = dense_ground.ground_plane(pts, GROUND)
    assert p is not None
    assert abs(1.0 / np.linalg.norm(p) - 1.0 / np.linalg.norm(truth)) < 0.01
    cos = p @ truth / np.linalg.norm(p) / np.linalg.norm(truth)
    assert np.degrees(np.arccos(min(cos, 1.0))) < 0.2
    wall = np.stack([x, rng.uniform(-1.0, 1.0, len(x)), np.full_like(x, 8.0)], 1)
    assert dense_ground.ground_plane(wall, GROUND) is None  # faces the camera
