"""Far planes (dense_facade) on a rendered building front 40 m away, against the scene mesh."""
import functools

from absscale_ros.core import dense_evaluation, dense_facade, dense_stereo, dense_sweep
from absscale_ros.sim import camera as simcam
from absscale_ros.sim import render, scenes
from keyframe_scenes import _look_at
import numpy as np

SWEEP = dense_sweep.SweepConfig()
FACADE = dense_facade.FacadeConfig(enabled=True)


@functools.lru_cache(maxsize=1)
def _facade_views() -> tuple:
    """Three 1280x720 views of a window ribbon's building 40 m away, 5 m apart sideways."""
    scene = scenes.build_scene('outdoor_cube', 3)
    window = next(s for s, m in enumerate(scene.surface_material)
                  if scene.materials[m].texture == 'window')
    centre = scene.vertices_m[scene.triangles[scene.tri_surface == window]].reshape(-1, 3)
    centre = centre.mean(0)
    n = scene.normals[window] * [1.0, 1.0, 0.0]
    n /= np.linalg.norm(n)
    side = np.cross(n, [0.0, 0.0, 1.0])
    eye = centre + 40.0 * n
    eye[2] = 1.6
    poses = [_look_at(eye + k * side, centre + k * side) for k in (-5.0, 0.0, 5.0)]
    cam = simcam.make_camera(np.random.default_rng(3), 1280, 720)
    renderer = render.Renderer(scene, cam)
    images = [np.clip(renderer.render(T).colour, 0, 255).astype(np.uint8)[..., ::-1].copy()
              for T in poses]
    return images, cam, poses, dense_evaluation.SceneMesh(scene.vertices_m, scene.triangles)


def test_far_planes_fill_the_facade_within_centimetres() -> None:
    images, cam, poses, mesh = _facade_views()
    small, _ = dense_stereo.working_image(images[1], cam, dense_stereo.StereoConfig())
    _, grey, K = dense_sweep.pinhole_view(small, cam.resized(640, 360), SWEEP)
    others, fine = [], []
    for k in (0, 2):
        view = dense_sweep.pinhole_view(
            dense_stereo.working_image(images[k], cam, dense_stereo.StereoConfig())[0],
            cam.resized(640, 360), SWEEP)
        T = dense_stereo.relative_pose(poses[1], poses[k])
        others.append((view[1], T))
        fine.append((dense_facade.fine_view(images[k], cam)[0].astype(np.float32), T))
    ref, K_fine = dense_facade.fine_view(images[1], cam)
    fine_ref = (ref.astype(np.float32), fine, K_fine)
    covered = np.zeros(grey.shape, bool)
    planes = dense_facade.facade_planes(grey, others, K, covered, FACADE, SWEEP, fine_ref)
    assert planes and planes[0][2] > 0  # a plane, refined
    depth = dense_facade.facade_fill(grey, others, K, covered, [p[:2] for p in planes],
                                     FACADE, fine_ref)
    m = dense_stereo.DepthMap(depth, np.zeros(grey.shape + (3,), np.uint8), K, np.eye(3), -1,
                              np.eye(4))
    pts = m.points_camera()[0]
    world = pts @ poses[1][:3, :3].T + poses[1][:3, 3]
    dist = mesh.distance(world)
    # A tenth of the view at least, most of it within the 5 cm of the completeness radius
    # (one pixel of parallax over 5 m at 40 m is 1.3 m at this scale: the plane does it).
    assert len(pts) > 0.1 * depth.size
    assert np.median(dist) < 0.05 and np.mean(dist > 0.3) < 0.15  # beside it: sky, ground
    # Without the photometric refinement the plane of the far sweep alone is further off.
    plain = dense_facade.facade_planes(grey, others, K, covered,
                                       dense_facade.FacadeConfig(enabled=True, refine=False),
                                       SWEEP)
    raw = dense_facade.facade_fill(grey, others, K, covered, [p[:2] for p in plain], FACADE,
                                   fine_ref)
    m.depth = raw
    raw_dist = mesh.distance(m.points_camera()[0] @ poses[1][:3, :3].T + poses[1][:3, 3])
    assert np.median(raw_dist) > np.median(dist)


def test_refinement_samples_more_pixels_than_a_remap_side_holds() -> None:
    # A large façade drives the refinement with more than 32767 pixels (lag 8 on outdoor 65):
    # the samples are bilinear whatever their number.
    rng = np.random.default_rng(0)
    img = rng.random((720, 1280)).astype(np.float32)
    x, y = (rng.random(50000) * [[1270], [710]]).astype(np.float32)
    xi, yi = x.astype(int), y.astype(int)
    ax, ay = x - xi, y - yi
    expected = img[yi, xi] * (1 - ax) * (1 - ay) + img[yi, xi + 1] * ax * (1 - ay) + \
        img[yi + 1, xi] * (1 - ax) * ay + img[yi + 1, xi + 1] * ax * ay
    assert np.abs(dense_facade._sample(img, x, y) - expected).max() < 1e-5
