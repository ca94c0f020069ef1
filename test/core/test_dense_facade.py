"""Far planes (dense_facade) on a rendered building front 40 m away, against the scene mesh."""
import dataclasses
import functools

from absscale_ros.core import dense_facade, dense_fusion, dense_stereo, dense_sweep
from absscale_ros.sim import render, scenes
import dense_scenes
from keyframe_scenes import _look_at
import numpy as np
import pytest

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
    return dense_scenes.outdoor_views([_look_at(eye + k * side, centre + k * side)
                                       for k in (-5.0, 0.0, 5.0)])


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


def _fixture_planes(cfg: dense_facade.FacadeConfig) -> tuple:
    """The middle view's far planes and fill inputs (sweep scale and full size)."""
    images, cam, poses, mesh = _facade_views()
    views = [dense_sweep.pinhole_view(
        dense_stereo.working_image(img, cam, dense_stereo.StereoConfig())[0],
        cam.resized(640, 360), SWEEP) for img in images]
    others = [(views[k][1], dense_stereo.relative_pose(poses[1], poses[k])) for k in (0, 2)]
    fine = [(dense_facade.fine_view(images[k], cam)[0].astype(np.float32), T)
            for k, (_, T) in zip((0, 2), others)]
    ref, K_fine = dense_facade.fine_view(images[1], cam)
    fine_ref = (ref.astype(np.float32), fine, K_fine)
    grey, K = views[1][1], views[1][2]
    covered = np.zeros(grey.shape, bool)
    planes = dense_facade.facade_planes(grey, others, K, covered, cfg, SWEEP, fine_ref)
    return grey, others, K, covered, planes, fine_ref, poses[1], mesh


def test_fill_check_in_the_candidates_box_equals_the_whole_image() -> None:
    # Only the candidates' box is warped (CPU); inside it the check is the same (up to the
    # rounding of the shifted homography).
    _, _, _, _, planes, fine_ref, _, _ = _fixture_planes(FACADE)
    grey, others, K_fine = fine_ref
    whole = dense_facade._consistent(grey, others, K_fine, planes[0][0], FACADE)
    box = (300, 100, 900, 500)
    inside = dense_facade._consistent(grey, others, K_fine, planes[0][0], FACADE, box)
    assert whole[100:500, 300:900].any()
    differ = np.mean(inside[107:493, 307:893] != whole[107:493, 307:893])
    assert differ < 1e-3, differ  # the shifted warp's rounding flips a threshold or two
    assert not inside[:100].any() and not inside[:, :300].any()


def test_plain_fill_only_between_agreeing_texture() -> None:
    # A plain pixel is filled only with textured agreement above and below it (or on both
    # sides): the plain wall between windows stays, the plain sky over the roof line goes
    # (measured: 955 -> 52 points more than 0.3 m off, 8148 -> 8141 within 5 cm).
    grey, others, K, covered, planes, fine_ref, pose, mesh = _fixture_planes(FACADE)
    out = []
    for reach in (0, 48):
        cfg = dataclasses.replace(FACADE, enclosed_px=reach)
        depth = dense_facade.facade_fill(grey, others, K, covered, [p[:2] for p in planes],
                                         cfg, fine_ref)
        m = dense_stereo.DepthMap(depth, np.zeros(grey.shape + (3,), np.uint8), K, np.eye(3),
                                  -1, np.eye(4))
        dist = mesh.distance(m.points_camera()[0] @ pose[:3, :3].T + pose[:3, 3])
        out.append((np.sum(dist > 0.3), np.sum(dist < 0.05)))
    (wrong, right), (wrong_e, right_e) = out
    assert wrong > 500 and wrong_e < wrong / 5
    assert right_e > 0.98 * right


def _true_depth(renderer: render.Renderer, T: np.ndarray, K: np.ndarray,
                shape: tuple[int, int]) -> np.ndarray:
    """True z of every pixel of a pinhole view (K, shape), inf for the sky."""
    v, u = np.mgrid[:shape[0], :shape[1]].reshape(2, -1).astype(np.float64)
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], 1)
    length = np.linalg.norm(rays, axis=1)
    t, _ = renderer.cast(T, (rays / length[:, None]).astype(np.float32))
    return (t / length).reshape(shape)


def test_near_points_of_a_neighbour_mark_what_stands_in_front_of_the_facade() -> None:
    # The neighbour's true near depth (the ground and posts under 20 m), seen from the
    # middle view: what it marks there is nearer than any façade, and it marks most of that.
    images, cam, poses, _ = _facade_views()
    renderer = render.Renderer(scenes.build_scene('outdoor_cube', 3), cam)
    cfg = dense_facade.FacadeConfig(enabled=True, occluders=1)
    fusion = dense_fusion.DenseFusion(dense_stereo.StereoConfig(), dense_fusion.FusionConfig(),
                                      SWEEP, cfg)
    for k in (0, 1):
        fusion.add_keyframe(k, images[k], cam)
        kf = fusion._frames[k]
        kf.pose = poses[k]
        kf.view = dense_sweep.pinhole_view(kf.image, kf.camera, SWEEP)
    _, grey, K = fusion._frames[1].view
    depth = _true_depth(renderer, poses[0], K, grey.shape)
    depth = np.where(depth < cfg.near_m, depth, 0.0).astype(np.float32)
    fusion._frames[0].depths[dense_fusion.SWEEP] = dense_stereo.DepthMap(
        depth, np.zeros(grey.shape + (3,), np.uint8), K, np.eye(3), -1, np.eye(4))
    marked = fusion._occluded([0, 1], 1)
    truth = _true_depth(renderer, poses[1], K, grey.shape)
    assert marked.sum() > 0.05 * marked.size
    assert np.mean(truth[marked] < cfg.near_m + 1.0) > 0.97  # nearer than a façade
    # of what is that near and in the neighbour's view, most is marked
    v, u = np.nonzero(truth < 0.9 * cfg.near_m)
    z = truth[v, u]
    pts = np.stack([(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z], 1)
    T = dense_stereo.relative_pose(poses[1], poses[0])  # middle camera -> neighbour's
    p = (pts @ T[:3, :3].T + T[:3, 3]) @ K.T
    seen = (p[:, 0] >= 0) & (p[:, 0] < p[:, 2] * grey.shape[1]) & (p[:, 1] >= 0) & \
        (p[:, 1] < p[:, 2] * grey.shape[0])
    assert np.mean(marked[v[seen], u[seen]]) > 0.8


def test_fill_at_full_size_when_the_heights_do_not_scale_alike() -> None:
    # Sizes are rounded at each scale (1242x375 -> 621x188 -> ...): the full-size view may be
    # shorter than the sweep view times the width ratio. The candidates' box stays inside it
    # (it reached 2 rows beyond and the fill raised ValueError, a shape mismatch).
    grey, others, K, covered, planes, (ref, fine, K_fine), _, _ = _fixture_planes(FACADE)
    everywhere = [(p, np.ones(grey.shape, bool)) for p, _, _ in planes]
    tall = dense_facade.facade_fill(grey, others, K, covered, everywhere, FACADE,
                                    (ref, fine, K_fine))
    short = dense_facade.facade_fill(grey, others, K, covered, everywhere, FACADE,
                                     (ref[:-2], [(f[:-2], T) for f, T in fine], K_fine))
    assert np.count_nonzero(tall) > 1000
    assert abs(np.count_nonzero(short) - np.count_nonzero(tall)) < 0.02 * np.count_nonzero(tall)


@pytest.mark.parametrize('bad', [{'ransac_sample': -1}, {'occluders': -1}, {'enclosed_px': -48},
                                 {'near_m': 200.0}, {'views': 0}, {'tolerance': 0.0}])
def test_a_bad_facade_config_is_refused(bad: dict) -> None:
    with pytest.raises(ValueError):
        dense_facade.FacadeConfig(**bad)
    dense_facade.FacadeConfig(ransac_sample=2000, occluders=3, enclosed_px=48, lag=8)
