"""
The published-landmark filter on a map reconstructed from rendered keyframes: it keeps exactly
the landmarks an independent (slow, exact) check accepts.
"""
from pathlib import Path
import sys

import numpy as np
import pytest

from absscale_ros.core import landmark_quality, sfm, sfm_outputs

sys.path.insert(0, str(Path(__file__).parent))
import sfm_scenes  # noqa: E402


@pytest.fixture(scope='module')
def engine() -> sfm.IncrementalSfm:
    seq = sfm_scenes.make_sequence('indoor_paper', 0, count=8)
    eng = sfm.IncrementalSfm(seq.camera, sfm.SfmConfig(), np.random.default_rng(7))
    for k, img in enumerate(seq.images_bgr):
        eng.add_keyframe(k, img)
    eng.finish()
    return eng


def test_filter_matches_an_exact_check(engine: sfm.IncrementalSfm) -> None:
    m, K = engine.current.map, engine.K
    cfg = landmark_quality.CloudConfig(min_observations=3, min_angle_deg=2.0, max_reproj_px=1.0)
    kept = set(landmark_quality.well_triangulated(m, K, cfg))
    worst: dict[int, float] = {}
    for lm_id, _, err in m.residuals_px(K):
        worst[lm_id] = max(worst.get(lm_id, 0.0), err)
    borderline, want = 0, set()
    for lm_id, lm in m.landmarks.items():
        centres = np.array([m.keyframes[k].T_world_cam[:3, 3] for k in lm.obs_px])
        angle = sfm_outputs.widest_angle_deg(lm.point_world, centres)
        borderline += abs(angle - cfg.min_angle_deg) < 0.05
        if len(lm.obs_px) >= 3 and angle >= cfg.min_angle_deg and worst[lm_id] <= 1.0:
            want.add(lm_id)
    # Every test is exercised: some landmarks fail, most pass.
    assert 0.3 * len(m.landmarks) < len(want) < len(m.landmarks)
    assert len(kept ^ want) <= borderline  # the angle is estimated, exact along a path
    xyz, rgb = sfm_outputs.cloud(m, K, cfg)
    assert xyz.shape == (len(kept), 3) and rgb.shape == (len(kept), 3) and rgb.dtype == np.uint8


def test_thresholds_only_remove(engine: sfm.IncrementalSfm) -> None:
    m, K = engine.current.map, engine.K
    loose = landmark_quality.CloudConfig(min_observations=2, min_angle_deg=0.0,
                                         max_reproj_px=1e9)
    assert len(landmark_quality.well_triangulated(m, K, loose)) == len(m.landmarks)
    counts = [len(landmark_quality.well_triangulated(m, K, landmark_quality.CloudConfig(
        min_observations=3, min_angle_deg=a))) for a in (0.0, 15.0, 30.0)]
    assert counts[0] > counts[1] > counts[2]
    with pytest.raises(ValueError):
        landmark_quality.CloudConfig(min_observations=1)


def test_widest_angle_anchor_is_the_least_aligned_ray(engine: sfm.IncrementalSfm) -> None:
    """The anchor ray, found by a minimum per landmark, is the one a full sort finds (the
    first of equals; a landmark of NaN rays gives NaN and leaves the others alone)."""
    m = engine.current.map
    lms = [lm for lm in m.landmarks.values() if len(lm.obs_px) >= 2]
    counts = np.array([len(lm.obs_px) for lm in lms])
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    T = np.array([m.keyframes[k].T_world_cam for lm in lms for k in lm.obs_px])
    pts = np.repeat(np.array([lm.point_world for lm in lms]), counts, axis=0)
    pts[starts[1]:starts[1] + counts[1]] = np.nan
    T[starts[2] + 1:starts[2] + counts[2], :3, 3] = T[starts[2], :3, 3]  # rays alike: ties

    rays = pts - T[:, :3, 3]
    rays /= np.maximum(np.linalg.norm(rays, axis=1, keepdims=True), 1e-12)
    group = np.repeat(np.arange(len(counts)), counts)
    mean = np.add.reduceat(rays, starts)[group]
    first = np.lexsort((np.sum(rays * mean, axis=1), group))[starts]  # the sort: slow
    cos = np.minimum.reduceat(np.sum(rays * rays[first][group], axis=1), starts)
    want = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    got = landmark_quality._widest_angles_deg(pts, T, counts, starts)
    assert np.isnan(got[1]) and np.array_equal(got, want, equal_nan=True)
    assert (got > 1.0).sum() > len(got) // 2  # most landmarks seen under a real angle


def test_cloud_observations_are_the_published_landmarks_own(engine: sfm.IncrementalSfm) -> None:
    """In the cloud's order: each published point reprojects onto its listed observations."""
    m, K = engine.current.map, engine.K
    cfg = landmark_quality.CloudConfig(min_observations=3, min_angle_deg=2.0, max_reproj_px=1.0)
    xyz, _ = sfm_outputs.cloud(m, K, cfg)
    obs = sfm_outputs.cloud_observations(m, K, cfg)
    T_of = {kf.stamp_ns: kf.T_world_cam for kf in m.keyframes.values()}
    assert len(obs) == len(xyz) > 20
    for point, (stamps, uv) in zip(xyz, obs):
        T = np.array([T_of[int(s)] for s in stamps])
        p_cam = np.einsum('nji,nj->ni', T[:, :3, :3], point - T[:, :3, 3])
        px = p_cam[:, :2] / p_cam[:, 2:] @ K[:2, :2].T + K[:2, 2]
        assert len(stamps) >= 3 and np.linalg.norm(px - uv, axis=1).max() <= 1.0 + 1e-9
