"""Plane fill of plain holes, on a rendered view of the indoor scene with its exact depth."""
import dataclasses
import functools

import cv2
from absscale_ros.core import dense_fill, dense_fusion, dense_stereo
from absscale_ros.core.types import CameraModel
from absscale_ros.sim import render, scenes
from dense_scenes import sideways_keyframes
from keyframe_scenes import _look_at
import numpy as np
import pytest

FILL = dense_fill.FillConfig(enabled=True)


@functools.lru_cache(maxsize=1)
def _view(seed: int = 3) -> tuple:
    """A 320x180 pinhole view (the sweep's) of the desk before the wall: bgr, float grey, K,
    exact z (inf: none), surface ids; 'measured' depth only where a window has texture, as
    stereo finds it (the plain wall and sheets left as holes)."""
    scene = scenes.build_scene('indoor_paper', seed)
    w = scene.walk
    target = np.array([w['target_x'], w['target_y'], w['target_z']])
    K = np.array([[260.0, 0.0, 159.5], [0.0, 260.0, 89.5], [0.0, 0.0, 1.0]])
    renderer = render.Renderer(scene, CameraModel(320, 180, K, np.zeros(5), 'plumb_bob'))
    T = _look_at(target + np.array([-0.4, -1.6, 0.9]), target)
    bgr = np.clip(renderer.render(T).colour, 0, 255).astype(np.uint8)[..., ::-1].copy()
    z, ids = renderer.depth(T)
    grey = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY).astype(np.float32)
    mu = cv2.boxFilter(grey, -1, (7, 7))
    sd = np.sqrt(np.maximum(cv2.boxFilter(grey * grey, -1, (7, 7)) - mu * mu, 0.0))
    measured = np.where(np.isfinite(z) & (sd >= FILL.plain_sd), z, 0.0).astype(np.float64)
    return bgr, grey, K, z, ids, measured


def _points(depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    v, u = np.nonzero(depth > 0)
    z = depth[v, u]
    return np.stack([(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z], axis=1)


@pytest.mark.parametrize('hull', [-1.0, 0.5])
def test_plain_holes_get_the_depth_of_the_plane_around_them(hull: float) -> None:
    _, grey, K, z, ids, measured = _view()
    fill = dataclasses.replace(FILL, rim_hull=hull)  # the wall lies between its rim points
    planes = dense_fill.scene_planes(_points(measured, K), fill)
    filled = dense_fill.fill(measured, grey, K, planes, fill)
    holes = (measured == 0) & np.isfinite(z)
    assert holes.mean() > 0.3  # the plain wall, the desk top, the sheets
    got = filled > 0
    assert np.all(measured[got] == 0)  # only holes are filled
    assert got.sum() > 0.5 * holes.sum()
    err = np.abs(filled[got] - z[got]) / z[got]
    # On the planes of the room: within the RANSAC tolerance almost everywhere.
    assert np.median(err) < 0.002 and np.mean(err > 0.01) < 0.02
    # The wall is filled: the surface with most hole pixels.
    wall = np.bincount(ids[holes]).argmax()
    assert got[ids == wall].mean() > 0.6


def test_a_plane_touching_a_hole_along_one_side_does_not_fill_it() -> None:
    _, grey, K, z, ids, measured = _view()
    planes = dense_fill.scene_planes(_points(measured, K), FILL)
    filled = dense_fill.fill(measured, grey, K, planes, FILL)
    holes = (measured == 0) & np.isfinite(z)
    wall = np.bincount(ids[holes]).argmax()
    # The plane that fills the wall's holes; the others alone (the desk top meets the wall
    # along its back edge only, the floor is hidden from it) must not fill them.
    on_wall = (filled > 0) & (ids == wall)
    v, u = np.nonzero(on_wall)
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones(len(u))], 1)
    fits = [np.median(np.abs(rays @ n * filled[v, u] - d)) for n, d in planes]
    others = [p for k, p in enumerate(planes) if k != int(np.argmin(fits))]
    assert len(others) >= 1
    alone = dense_fill.fill(measured, grey, K, others, FILL)
    assert (alone[ids == wall] > 0).mean() < 0.05
    assert not dense_fill.fill(measured, grey, K, [], FILL).any()


def test_fusion_with_the_fill_covers_more_of_the_wall_as_accurately() -> None:
    images, cam, poses, mesh = sideways_keyframes()
    clouds = []
    # lag 0: every keyframe filled (at the default 3, only the first 3 of 6 are: +3.7 % points)
    for fill in (dense_fill.FillConfig(), dataclasses.replace(FILL, lag=0)):
        fusion = dense_fusion.DenseFusion(dense_stereo.StereoConfig(scale=1.0),
                                          dense_fusion.FusionConfig(), fill=fill)
        for k, image in enumerate(images):
            fusion.add_keyframe(k, image, cam)
        fusion.update(dict(enumerate(poses)))
        while fusion.backlog:
            fusion.catch_up()
        clouds.append(fusion.cloud()[0])
    off, on = clouds
    assert len(on) > 1.1 * len(off)
    dist_off, dist_on = mesh.distance(off), mesh.distance(on)
    depth = np.median(np.linalg.norm(off - poses[0][:3, 3], axis=1))
    assert np.median(dist_on) <= np.median(dist_off) + 0.0005 * depth
    assert np.percentile(dist_on, 90) <= np.percentile(dist_off, 90) + 0.001 * depth


def test_a_new_sweep_adds_its_points_until_the_fill_rebuilds_the_keyframe() -> None:
    images, cam, poses, _ = sideways_keyframes()
    # One partner, chosen when a keyframe comes (on this walk a second side's pair would come
    # with the next keyframe, together with the sweep)
    fusion = dense_fusion.DenseFusion(dense_stereo.StereoConfig(scale=1.0),
                                      dense_fusion.FusionConfig(both_sides=False), fill=FILL)
    held = []
    for k, image in enumerate(images[:5]):  # one keyframe at a time, as a bag feeds them
        fusion.add_keyframe(k, image, cam)
        fusion.update({j: poses[j] for j in range(k + 1)})
        while fusion.backlog:
            fusion.catch_up()
        if k >= 1:
            held.append(np.asarray(fusion._frames[1].cloud.points).copy())
    held = [np.zeros((0, 3))] + held  # held[k]: after keyframe k came
    # Keyframe 1: its pair's points at once; its sweep (one keyframe later) adds its own points
    # and leaves those as they were; once its fill is due (3 later) every point is checked again.
    assert len(held[2]) > len(held[1]) and np.array_equal(held[2][:len(held[1])], held[1])
    assert np.array_equal(held[3], held[2])
    assert not np.array_equal(held[4][:len(held[1])], held[1])


def test_a_plane_is_not_extrapolated_beyond_its_rim_points() -> None:
    """
    A plain wall, 3 m away, measured on one patch only, framed by things before it (the
    room's objects and edges, which the rim may hold): its plane is known near the patch
    alone, and a tilt of it grows with the distance from there (indoor 77's far wall: filled
    -6 to +6 cm across the image). Filled between its rim points only, the patch's hole is
    not filled at all; between two patches, the wall between them is.
    """
    K = np.array([[260.0, 0.0, 159.5], [0.0, 260.0, 89.5], [0.0, 0.0, 1.0]])
    grey = np.full((180, 320), 120.0, np.float32)  # plain: every pixel without depth a hole
    measured = np.zeros((180, 320))
    measured[:12], measured[-12:], measured[:, :12], measured[:, -12:] = 2.0, 2.0, 2.0, 2.0
    measured[50:130, 110:210] = 3.0
    wall = [(np.array([0.0, 0.0, 1.0]), 3.0)]
    free = dense_fill.fill(measured, grey, K, wall, FILL)
    assert (free > 0).sum() > 20000 and np.allclose(free[free > 0], 3.0)
    between = dataclasses.replace(FILL, rim_hull=0.0)
    assert not dense_fill.fill(measured, grey, K, wall, between).any()
    measured[50:130, 110:210] = 0.0
    measured[20:160, 20:110], measured[20:160, 210:300] = 3.0, 3.0
    filled = dense_fill.fill(measured, grey, K, wall, between)
    assert (filled[21:159, 112:208] > 0).all() and not filled[:17].any()


def test_a_large_hole_takes_only_a_plane_some_view_measured_inside_it() -> None:
    """
    A plain wall that no view measured: its holes' rims hold only outlines (and, in stereo,
    their spill), so the plane they lie on is not known to be the wall's. With ``inside_px``
    a hole whose core is that large is filled only with a plane the neighbourhood's points
    reach into; smaller holes are bridged as before.
    """
    _, grey, K, z, ids, measured = _view()
    around = _points(measured, K)  # the views measured nothing inside the plain holes
    planes = dense_fill.scene_planes(around, FILL)
    strict = dataclasses.replace(FILL, inside_px=1000)
    free = dense_fill.fill(measured, grey, K, planes, FILL)
    blind = dense_fill.fill(measured, grey, K, planes, strict, around)
    count, labels, stats, _ = cv2.connectedComponentsWithStats((free > 0).astype(np.uint8), 4)
    large = [k for k in range(1, count) if stats[k, cv2.CC_STAT_AREA] > 4000]
    assert large and not any(blind[labels == k].any() for k in large)
    small = (labels > 0) & ~np.isin(labels, large)
    assert np.array_equal(blind[small], free[small])  # small holes: as before
    # Views that did measure the wall (a sparse sample of its true surface) let it be filled.
    seen = np.where(np.isfinite(z), z, 0.0)
    sampled = np.zeros_like(seen)
    sampled[::8, ::8] = seen[::8, ::8]
    filled = dense_fill.fill(measured, grey, K, planes, strict,
                             np.concatenate([around, _points(sampled, K)]))
    assert np.array_equal(filled, free)


@pytest.mark.parametrize('field', ['lag', 'max_planes', 'max_holes'])
def test_a_fill_config_that_cannot_fill_is_refused(field: str) -> None:
    """A negative lag, or no plane or hole to try, is a typo in a config, not a quiet no-op."""
    with pytest.raises(ValueError):
        dense_fill.FillConfig(**{field: -1 if field == 'lag' else 0})


def test_the_clouds_of_one_update_built_on_two_threads_are_the_same() -> None:
    images, cam, poses, _ = sideways_keyframes()
    clouds, together = [], []
    for threads in (1, 2):
        fusion = dense_fusion.DenseFusion(
            dense_stereo.StereoConfig(scale=1.0),
            dense_fusion.FusionConfig(both_sides=False, threads=threads), fill=FILL)
        built = fusion._built
        fusion._built = lambda builds: together.append(len(builds)) or built(builds)
        for k, image in enumerate(images[:5]):  # a new keyframe's cloud beside a fill's
            fusion.add_keyframe(k, image, cam)
            fusion.update({j: poses[j] for j in range(k + 1)})
        clouds.append(fusion.cloud())
    assert max(together) >= 2 and len(clouds[0][0]) > 1000
    assert all(np.array_equal(a, b) for a, b in zip(*clouds))
