"""
Cube vertex matching on a rendered approach along a top edge of the cube, seen nearly end-on.

Fresh outdoor 45 walked towards the cube along the line of one of its top edges: corners 4 and
6 lay 2.5-5 px apart, each within 2.2 px of the other's epipolar line, and the colour score
matched them to each other (landmarks 1.3 m and 2.1 m off, and one corner's landmark starting
from the other's view). Here keyframes are rendered on such a path (true poses, true vertices),
and every pair of them is matched.
"""
import itertools
from pathlib import Path
import sys

import numpy as np
import pytest

from absscale_ros.core import vertex_matching as vm
from absscale_ros.sim import camera as simcam
from absscale_ros.sim import render, scenes

sys.path.insert(0, str(Path(__file__).parent))
import sfm_scenes  # noqa: E402


@pytest.fixture(scope='module')
def end_on() -> tuple[np.ndarray, list[np.ndarray], np.ndarray, list[np.ndarray]]:
    """K, keyframe images, poses and (V, 2) px of the cube's vertices, the farthest one NaN."""
    seed = 2
    scene = scenes.build_scene('outdoor_cube', seed)
    camera = simcam.make_camera(scenes.streams(seed)['camera'], 640, 360)
    renderer = render.Renderer(scene, camera)
    v = scene.targets[0].vertices_world_m
    top = np.flatnonzero(v[:, 2] > v[:, 2].mean())
    a, b = next((a, b) for a, b in itertools.combinations(top, 2)
                if abs(np.linalg.norm(v[a] - v[b]) - 0.8) < 1e-3)  # a top edge
    along = (v[a] - v[b]) * [1.0, 1.0, 0.0]
    along /= np.linalg.norm(along)
    across = np.array([-along[1], along[0], 0.0])
    rng = np.random.default_rng(0)
    images, poses, pxs = [], [], []
    for k in range(8):  # 18.5 -> 12.9 m out along the edge, drifting a little sideways (45's)
        eye = v[a] + (18.5 - 0.8 * k) * along + (0.6 + 0.12 * k) * across + [0.0, 0.0, 0.8]
        T = sfm_scenes.look_at(eye, v.mean(axis=0) + rng.normal(0.0, 0.2, 3))
        colour = renderer.render(T).colour
        gain = 255.0 if float(colour.max()) <= 2.0 else 1.0
        rgb = np.clip(colour * gain + 0.5, 0.0, 255.0).astype(np.uint8)
        images.append(np.ascontiguousarray(rgb[..., ::-1]))
        px = simcam.project(camera, (v - T[:3, 3]) @ T[:3, :3])
        px[int(np.argmax(np.linalg.norm(v - T[:3, 3], axis=1)))] = np.nan  # hidden by the cube
        poses.append(T)
        pxs.append(px)
    return camera.K, images, np.array(poses), pxs


def _match_all(end_on, cfg: vm.VertexMatchConfig) -> list[tuple[int, int, int, int]]:
    """(keyframe a, keyframe b, true corner in a, true corner in b) of every match."""
    K, images, poses, pxs = end_on
    out = []
    for a, b in itertools.combinations(range(len(images)), 2):
        vis = np.flatnonzero(np.isfinite(pxs[a][:, 0]) & np.isfinite(pxs[b][:, 0]))
        va, vb = pxs[a][vis], pxs[b][vis]
        pairs = vm.match_cube(va, vb, vm.windows(images[a], va, cfg),
                              vm.windows(images[b], vb, cfg),
                              vm.fundamental(K, poses[a], poses[b]), cfg)
        out += [(a, b, int(vis[i]), int(vis[j])) for i, j in pairs]
    return out


def test_without_the_ambiguity_rule_the_colour_score_swaps_end_on_corners(end_on) -> None:
    # The scene reproduces 45's failure: epipolar band and colour score alone pair two corners.
    matches = _match_all(end_on, vm.VertexMatchConfig(ambiguous_px=0.0))
    assert sum(ca != cb for _, _, ca, cb in matches) >= 2


def test_end_on_corners_are_left_unmatched_and_the_others_still_match(end_on) -> None:
    cfg = vm.VertexMatchConfig()
    matches = _match_all(end_on, cfg)
    assert all(ca == cb for _, _, ca, cb in matches)
    # Every corner with no other corner within ambiguous_px in either view is still matched.
    _, images, _, pxs = end_on
    found = {(a, b, c) for a, b, c, _ in matches}
    clear = 0
    for a, b in itertools.combinations(range(len(images)), 2):
        for c in np.flatnonzero(np.isfinite(pxs[a][:, 0]) & np.isfinite(pxs[b][:, 0])):
            gaps = [np.delete(np.linalg.norm(p - p[c], axis=1), c) for p in (pxs[a], pxs[b])]
            if all(np.nanmin(g) >= cfg.ambiguous_px for g in gaps):
                assert (a, b, int(c)) in found
                clear += 1
    assert clear >= 20
