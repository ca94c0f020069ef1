"""
The final pass that links older keyframes to landmarks triangulated after them (``finish``):
the guided search during the run only ever links a new keyframe to older landmarks.
"""
from dataclasses import replace
from pathlib import Path
import sys

import numpy as np

from absscale_ros.core import sfm, twoview

sys.path.insert(0, str(Path(__file__).parent))
import sfm_scenes  # noqa: E402


def test_older_keyframes_are_linked_to_later_landmarks() -> None:
    seq = sfm_scenes.make_sequence('outdoor_cube', 1, count=10)
    engine = sfm.IncrementalSfm(seq.camera, sfm.SfmConfig(), np.random.default_rng(7))
    for k, img in enumerate(seq.images_bgr):
        engine.add_keyframe(k, img)
    m, cfg = engine.current.map, engine.cfg
    assert len(m.keyframes) == 10
    engine.cfg = replace(cfg, local_cfg=replace(cfg.local_cfg, final_keyframes=0))
    assert engine._link_back(m) == 0  # off
    engine.cfg = cfg
    before = {i: dict(lm.obs_px) for i, lm in m.landmarks.items()}
    added = engine._link_back(m)
    new = [(i, k) for i, lm in m.landmarks.items() for k in lm.obs_px if k not in before[i]]
    assert added == len(new) > 50
    # Backwards in time: a keyframe older than every view the landmark had.
    assert sum(k < min(before[i]) for i, k in new) > 0.2 * len(new)
    for i, k in new:
        uv = twoview.project(engine.K, m.keyframes[k].T_world_cam,
                             m.landmarks[i].point_world[None])[0]
        assert np.linalg.norm(uv - m.landmarks[i].obs_px[k]) <= cfg.local_cfg.final_radius_px
        assert m.keyframes[k].landmark_of.tolist().count(i) == 1  # the keypoint is tied to it
    assert engine.finish().reprojection_rms_px <= 1.0
