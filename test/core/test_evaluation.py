"""The evaluation finds true landmark points without alignment and measures lengths in mm/m."""
from absscale_ros.core import evaluation
from absscale_ros.core.types import CameraModel
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

CAM = CameraModel(640, 480, np.array([[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]]))


def _wall_truth(poses_gt: np.ndarray):
    """Ground truth of a scene that is one wall at z = 10 m, seen by cameras ``poses_gt``."""
    def truth(frame: int, px: np.ndarray) -> np.ndarray:
        pose = poses_gt[frame]
        rays = np.column_stack([(px - [319.5, 239.5]) / 500.0, np.ones(len(px))])
        rays_w = rays @ Rotation.from_quat(pose[3:]).as_matrix().T
        t = (10.0 - pose[2]) / rays_w[:, 2]
        return pose[:3] + t[:, None] * rays_w
    return truth


def test_true_points_and_length_errors_of_a_perfect_and_a_stretched_map() -> None:
    rng = np.random.default_rng(0)
    poses = np.array([[x, 0.0, 0.0, 0, 0, 0, 1] for x in (0.0, 0.5, 1.0)])
    pts = np.column_stack([rng.uniform(-3, 3, 200), rng.uniform(-2, 2, 200), np.full(200, 10.)])
    truth = _wall_truth(poses)
    found = evaluation.landmark_truth(pts, poses, [0, 1, 2], CAM, truth)
    ok = np.isfinite(found).all(axis=1)
    assert ok.sum() > 100 and np.allclose(found[ok], pts[ok], atol=1e-9)
    exact = evaluation.length_errors(pts, found, rng)
    assert exact.count > 500 and exact.max < 1e-6
    stretched = evaluation.length_errors(pts * 1.002, found, rng)  # 2 mm/m too long
    assert stretched.mean == pytest.approx(2.0, abs=1e-6)


def test_true_scale_of_a_trajectory() -> None:
    rng = np.random.default_rng(1)
    gt = rng.normal(size=(10, 3))
    R = Rotation.from_rotvec([0.1, 0.2, 0.3]).as_matrix()
    unscaled = (gt @ R) / 0.37 + 5.0
    assert evaluation.true_scale(unscaled, gt) == pytest.approx(0.37)


def test_truth_is_the_median_of_agreeing_keyframes_and_rejects_a_hidden_landmark() -> None:
    rng = np.random.default_rng(2)
    poses = np.array([[x, 0.0, 0.0, 0, 0, 0, 1] for x in (0.0, 0.3, 0.6, 0.9, 1.2)])
    pts = np.column_stack([rng.uniform(-2, 2, 300), rng.uniform(-1.5, 1.5, 300),
                           np.full(300, 10.)])
    wall = _wall_truth(poses)

    def noisy(frame: int, px: np.ndarray) -> np.ndarray:  # each view's hit is off by ~1 mm
        hits = wall(frame, px) + rng.normal(scale=0.001, size=(len(px), 3))
        if frame == 4:
            hits[:10, 2] -= 0.5  # the first ten are hidden behind something in keyframe 4
        return hits

    one = evaluation.landmark_truth(pts, poses, [0, 1, 2, 3, 4], CAM, noisy, views=2,
                                    agree_m=0.01)
    four = evaluation.landmark_truth(pts, poses, [0, 1, 2, 3, 4], CAM, noisy)
    ok = np.isfinite(four).all(axis=1)
    assert ok.sum() > 200 and not ok[:10].any()  # hidden in one of its views: no truth
    err_one = np.linalg.norm(one - pts, axis=1)
    err_four = np.linalg.norm(four - pts, axis=1)
    assert np.nanmedian(err_four[ok]) < 0.8 * np.nanmedian(err_one[ok])
