"""Known-length factors inside the bundle adjustment recover the metric scale of a map."""
from pathlib import Path
import sys

import numpy as np
import pytest

from absscale_ros.core import features as feat, metric_ba, scale, sfm_map
from absscale_ros.core.errors import NotObservableError

sys.path.insert(0, str(Path(__file__).parent))
from sfm_scenes import look_at  # noqa: E402

K = np.array([[800.0, 0.0, 640.0], [0.0, 800.0, 360.0], [0.0, 0.0, 1.0]])
TRUE_FACTOR = 2.5  # metres per map unit of the synthetic map


def _project(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    c = T[:3, :3].T @ (p - T[:3, 3])
    return (K @ (c / c[2]))[:2]


def _map(rng: np.random.Generator, noise_px: float) -> tuple[sfm_map.SfmMap, list[int]]:
    """A 0.8 m cube and a scene seen by 8 cameras on an arc, stored in map units."""
    cube_m = scale.model_vertices_m('cube', (0.8,)) + [2.0, 0.0, 0.0]
    scene_m = rng.uniform([0.0, -3.0, -1.0], [6.0, 3.0, 2.0], (150, 3)) + [3.0, 0.0, 0.0]
    empty = feat.Features(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 128), np.float32),
                          np.zeros((0, 3), np.uint8))
    m = sfm_map.SfmMap()
    poses_m = [look_at(np.array([-3.0, y, 1.5]), np.array([3.0, 0.0, 0.5]))
               for y in np.linspace(-2.0, 2.0, 8)]
    for i, T in enumerate(poses_m):
        T_map = T.copy()
        T_map[:3, 3] /= TRUE_FACTOR
        m.keyframes[i] = sfm_map.MapKeyframe(i, i, T_map, empty, np.zeros(0, np.int64))
    cube_ids = []
    for j, p in enumerate(np.vstack([cube_m, scene_m])):
        # The map's points start off their true place (a first SfM estimate) in map units.
        lm = m.add_landmark(p / TRUE_FACTOR + rng.normal(0.0, 0.002, 3), (0, 0, 0),
                            (0, j) if j < 8 else None)
        for i, T in enumerate(poses_m):
            m.observe(lm, i, _project(T, p) + rng.normal(0.0, noise_px, 2))
        if j < 8:
            cube_ids.append(lm)
    return m, cube_ids


def _cube_object(m: sfm_map.SfmMap, ids: list[int]) -> scale.ObjectVertices:
    pts = np.array([m.landmarks[i].point_world for i in ids])
    return scale.ObjectVertices('cube', (0.8,), pts, np.full(8, 8), np.full(8, 20.0))


def test_length_factors_put_the_map_in_metres() -> None:
    m, ids = _map(np.random.default_rng(3), noise_px=0.3)
    cfg = scale.ScaleConfig()
    known = metric_ba.constraints(m, _cube_object(m, ids), ids, cfg)
    assert len(known) == 28  # every pair of 8 vertices: edges, face and space diagonals
    assert sorted({round(c.length_m, 4) for c in known}) == [0.8, 1.1314, 1.3856]
    factor, centres = metric_ba.adjust(m, K, known, TRUE_FACTOR * 1.05,
                                       metric_ba.LengthFactorConfig())
    assert factor == pytest.approx(TRUE_FACTOR, rel=2e-3)  # started 5 % off
    first = m.keyframes[0].T_world_cam[:3, 3] * TRUE_FACTOR * 1.05
    np.testing.assert_allclose(centres[0], first, atol=1e-6)  # the held camera stays put


def test_no_lengths_no_metric_adjustment() -> None:
    m, ids = _map(np.random.default_rng(4), noise_px=0.3)
    few = scale.ObjectVertices('cube', (0.8,), np.array([m.landmarks[i].point_world
                                                         for i in ids[:2]]),
                               np.full(2, 8), np.full(2, 20.0))
    with pytest.raises(NotObservableError):
        metric_ba.constraints(m, few, ids[:2], scale.ScaleConfig())
    with pytest.raises(NotObservableError):
        metric_ba.adjust(m, K, [], 1.0, metric_ba.LengthFactorConfig())
