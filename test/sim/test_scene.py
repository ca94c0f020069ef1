"""Scenes: target geometry, colours, variants and determinism."""
import numpy as np
import pytest

from absscale_ros.sim import scenes, targets
from absscale_ros.sim.scene import CUBE_FACES


@pytest.mark.parametrize('top', ['purple', 'red', 'yellow'])
def test_cube_geometry_and_colours(top: str) -> None:
    cube = targets.cube(np.array([1.0, 2.0]), 0.0, 0.7, top)
    v = cube.vertices_world_m
    assert len(cube.edges) == 12
    for a, b in cube.edges:
        assert np.linalg.norm(v[a] - v[b]) == pytest.approx(0.8, abs=1e-12)
    assert v[:, 2].min() == pytest.approx(0.0) and v[:, 2].max() == pytest.approx(0.8)
    centre = v.mean(axis=0)
    for fid, ids in enumerate(cube.faces):
        p = v[list(ids)]
        normal = np.cross(p[1] - p[0], p[2] - p[0])
        assert np.dot(normal, p.mean(axis=0) - centre) > 0  # counter-clockwise from outside
        axis, sign = CUBE_FACES[fid]
        opposite = CUBE_FACES.index((axis, -sign))
        assert cube.colours[fid] == cube.colours[opposite]
    top_face = int(np.argmax([v[list(f)][:, 2].mean() for f in cube.faces]))
    assert cube.colours[top_face] == top
    for i in range(8):  # every vertex touches one face of each colour
        assert {cube.colours[f] for f, ids in enumerate(cube.faces) if i in ids} == \
            {'red', 'yellow', 'purple'}


def test_cube_colours_are_saturated_with_expected_hues() -> None:
    import colorsys
    for name, hue in (('red', 0.0), ('yellow', 55.0), ('purple', 290.0)):
        h, s, _ = colorsys.rgb_to_hsv(*targets.colour_rgb(name))
        assert abs((h * 360.0 - hue + 180.0) % 360.0 - 180.0) < 1.0 and s > 0.7


@pytest.mark.parametrize('kind,size', [('letter', (0.2159, 0.2794)), ('a4', (0.210, 0.297))])
def test_sheet_size(kind: str, size: tuple[float, float]) -> None:
    sheet = targets.sheet(kind, np.array([1.0, 1.0, 0.75]), 0.3)
    v = sheet.vertices_world_m
    assert np.linalg.norm(v[1] - v[0]) == pytest.approx(size[0], abs=1e-12)
    assert np.linalg.norm(v[2] - v[1]) == pytest.approx(size[1], abs=1e-12)
    assert np.cross(v[1] - v[0], v[2] - v[1])[2] > 0  # counter-clockwise from above


def test_indoor_variants_cycle_with_seed() -> None:
    got = {seed: scenes.build_scene('indoor_paper', seed) for seed in range(4)}
    assert [got[s].targets[0].name for s in range(4)] == ['letter', 'a4', 'letter', 'letter']
    assert got[2].targets[0].vertices_world_m[:, 2].max() < 0.01  # on the floor
    assert got[0].targets[0].vertices_world_m[:, 2].min() > 0.7  # on the desk
    for s in range(4):
        w = got[s].walk
        assert 3.0 <= w['room_x1'] + 0.35 <= 7.0 and 3.0 <= w['room_y1'] + 0.35 <= 7.2


def test_scenes_are_deterministic_and_differ_by_seed() -> None:
    a = scenes.build_scene('outdoor_cube', 5)
    b = scenes.build_scene('outdoor_cube', 5)
    c = scenes.build_scene('outdoor_cube', 8)
    assert np.array_equal(a.vertices_m, b.vertices_m) and np.array_equal(a.triangles, b.triangles)
    assert a.vertices_m.shape != c.vertices_m.shape or not np.allclose(a.vertices_m, c.vertices_m)


def test_distractor_and_occlusion_variants() -> None:
    plain = scenes.build_scene('outdoor_cube', 0)
    busy = scenes.build_scene('outdoor_cube', 0, {'distractors': True, 'occluded': True})
    assert not plain.distractors
    colours = {d['colour'] for d in busy.distractors}
    assert {'red', 'yellow', 'purple', 'white'} <= colours
    whites = [d for d in busy.distractors if d['kind'] == 'white_rectangle']
    for d in whites:
        assert sorted(d['size_m']) not in ([0.2159, 0.2794], [0.210, 0.297])
    indoor = scenes.build_scene('indoor_paper', 12)  # seed 12: distractors + occlusion
    assert indoor.variant['distractors'] and indoor.variant['occluded']
    assert any(p['label'] == 'occluding mug edge 0-1' for p in indoor.point_pairs)


def test_unknown_scene_and_variant_raise() -> None:
    with pytest.raises(ValueError):
        scenes.build_scene('moon', 0)
    with pytest.raises(ValueError):
        scenes.build_scene('indoor_paper', 0, {'colour': 'blue'})
    with pytest.raises(ValueError):
        scenes.build_scene('indoor_paper', 0, {'support': 'ceiling'})


@pytest.mark.parametrize('name', ['indoor_paper', 'outdoor_cube'])
def test_scenes_fit_the_renderer(name: str) -> None:
    """The renderer gathers per-face data with 8-bit ids: at most 255 faces per scene."""
    for seed in range(16):
        assert len(scenes.build_scene(name, seed).normals) <= 255
