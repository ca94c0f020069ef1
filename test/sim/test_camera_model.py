"""Simulated camera: projection matches OpenCV, and the ray grid inverts it exactly."""
import cv2
import numpy as np
import pytest

from absscale_ros.sim import camera as simcam


@pytest.mark.parametrize('seed', [0, 1, 2, 3])
def test_projection_matches_opencv(seed: int) -> None:
    rng = np.random.default_rng(seed)
    cam = simcam.make_camera(rng)
    pts = np.column_stack([rng.uniform(-4, 4, 500), rng.uniform(-2.5, 2.5, 500),
                           rng.uniform(1.0, 30.0, 500)])
    ours = simcam.project(cam, pts)
    theirs, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), cam.K, cam.dist)
    assert np.max(np.abs(ours - theirs.reshape(-1, 2))) < 1e-6


@pytest.mark.parametrize('size', [(1280, 720), (1920, 1080), (640, 360)])
def test_rays_through_pixels_project_back(size: tuple[int, int]) -> None:
    cam = simcam.make_camera(np.random.default_rng(7), *size)
    hfov = np.rad2deg(2 * np.arctan2(size[0] / 2, cam.K[0, 0]))
    assert 60.0 <= hfov <= 70.0
    pixels = simcam.pixel_grid(size[0], size[1], 7, (0.25, 0.5))
    dirs = simcam.ray_directions(cam, pixels).astype(np.float64)
    back = simcam.project(cam, dirs * 5.0)
    assert np.max(np.abs(back - pixels)) < 1e-4  # float32 directions: ~1e-5 px


def test_distortion_is_mild_barrel() -> None:
    cam = simcam.make_camera(np.random.default_rng(0))
    assert cam.distortion_model == 'plumb_bob' and len(cam.dist) == 5
    corner = np.array([[0.0, 0.0]])
    xy = simcam.undistort_pixels(cam, corner)
    ideal = cam.K[:2, :2] @ xy[0] + cam.K[:2, 2]
    shift = np.linalg.norm(ideal - corner[0])
    assert 5.0 < shift < 120.0  # noticeable but mild at the image corner
