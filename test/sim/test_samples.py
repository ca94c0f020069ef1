"""The committed sample bags: valid truth, 10-20 s each, 20 MB together at most."""
from pathlib import Path

import numpy as np
import pytest

from absscale_ros import bagio
from absscale_ros.sim import groundtruth

BAGS = Path(__file__).resolve().parents[2] / 'bags'
SAMPLES = ['indoor_paper_sample.mcap', 'outdoor_cube_sample.mcap']


def test_samples_fit_the_size_budget() -> None:
    files = [BAGS / s for s in SAMPLES] + [BAGS / (s + '.gt.json') for s in SAMPLES]
    assert sum(f.stat().st_size for f in files) <= 20e6


@pytest.mark.parametrize('name', SAMPLES)
def test_sample_truth_matches_its_bag(name: str) -> None:
    gt = groundtruth.load(BAGS / (name + '.gt.json'))
    assert gt['scene']['name'] == name.replace('_sample.mcap', '')
    assert (gt['camera']['width'], gt['camera']['height']) == (1280, 720)
    frames = gt['frames']
    assert 10.0 <= len(frames) / gt['bag']['fps'] <= 20.0
    with bagio.open_bag(BAGS / name) as reader:
        stamps = [m.stamp_ns for m in reader.messages([gt['bag']['image_topic']])]
    assert stamps == [f['stamp_ns'] for f in frames]
    seen = [f['targets'][0]['covers_min_area'] for f in frames]
    assert np.mean(seen) > 0.3
    assert len(gt['pure_rotation_segments']) == 2
