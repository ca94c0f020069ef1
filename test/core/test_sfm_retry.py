"""
A keyframe the recent keyframes do not register at the strict PnP threshold tries the looser
one once the map holds a few keyframes: the indoor sample's approach to the table (keyframes
11-19 of the selector's choice) split in two without it.
"""
import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from absscale_ros.core import align, sfm
from absscale_ros.tools import bench_sfm

BAG = str(Path(__file__).parents[2] / 'bags' / 'indoor_paper_sample.mcap')
STAMPS = [1700000005666666667, 1700000005800000000, 1700000005966666667, 1700000006133333333,
          1700000006300000000, 1700000006466666667, 1700000006600000000, 1700000006800000000,
          1700000007133333333]


def _run(tmp_path: Path, cfg: sfm.SfmConfig) -> tuple[sfm.IncrementalSfm, list[np.ndarray]]:
    report = tmp_path / 'report.json'
    report.write_text(json.dumps({'nodes': {'sfm': {'keyframe_stamps_ns': STAMPS}}}))
    parser = argparse.ArgumentParser()
    bench_sfm.add_arguments(parser)
    args = parser.parse_args([BAG, '--keyframes-from', str(report)])
    camera, _, frames = bench_sfm._from_bag(BAG, args)
    engine = sfm.IncrementalSfm(camera, cfg, np.random.default_rng(0))
    truth = []
    for stamp, img, T, _ in frames:
        engine.add_keyframe(stamp, img)
        truth.append(T)
    engine.finish()
    return engine, truth


def test_a_looser_retry_joins_the_indoor_samples_approach_without_bending_it(tmp_path) -> None:
    strict, _ = _run(tmp_path, replace(sfm.SfmConfig(), retry_pnp_px=0.0))
    assert len(strict.segments) == 2
    engine, truth = _run(tmp_path, sfm.SfmConfig())
    assert len(engine.segments) == 1 and len(engine.current.map.keyframes) == len(STAMPS)
    ids, T = engine.current.map.poses()
    gt = np.array([truth[i] for i in ids])
    s, R, t = align.umeyama(T[:, :3, 3], gt[:, :3, 3])
    path_m = float(np.sum(np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1)))
    assert align.rmse(align.apply(s, R, t, T[:, :3, 3]), gt[:, :3, 3]) < 0.003 * path_m


def test_the_retry_threshold_is_checked() -> None:
    for bad in ({'retry_pnp_px': -1.0}, {'retry_min_keyframes': 2}):
        with pytest.raises(ValueError):
            replace(sfm.SfmConfig(), **bad)
