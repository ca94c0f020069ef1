"""PLY and TUM files written by runs read back exactly (to float precision)."""
from pathlib import Path

from absscale_ros.core import cloud
import numpy as np


def test_ply_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(50, 3))
    cols = rng.integers(0, 256, size=(50, 3)).astype(np.uint8)
    cloud.write_ply(tmp_path / 'c.ply', pts, cols)
    got, got_cols = cloud.read_ply(tmp_path / 'c.ply')
    assert np.allclose(got, pts) and np.array_equal(got_cols, cols)


def test_tum_round_trip_keeps_nanoseconds(tmp_path: Path) -> None:
    stamps = np.array([1_700_000_000_000_000_001, 1_700_000_000_033_333_333], np.int64)
    poses = np.array([[1, 2, 3, 0, 0, 0, 1], [4, 5, 6, 0, 0, 0.6, 0.8]], float)
    cloud.write_tum(tmp_path / 't.tum', stamps, poses)
    got_stamps, got_poses = cloud.read_tum(tmp_path / 't.tum')
    assert np.array_equal(got_stamps, stamps) and np.allclose(got_poses, poses)
    assert (tmp_path / 't.tum').read_text().startswith('1700000000.000000001 1.0')
