"""Frame preparation: resize and undistortion keep the geometry; calibration files; gaps."""
from pathlib import Path

from absscale_ros.core import calibration, errors, ingest
from absscale_ros.core.types import CameraModel
import cv2
import numpy as np
import pytest

CAM = CameraModel(1280, 720, np.array([[900.0, 0, 652.3], [0, 901.0, 355.1], [0, 0, 1]]),
                  np.array([-0.1, 0.03, 0.0004, -0.0003, 0.0]), 'plumb_bob')
POINTS_CAM_M = np.array([[0.5, 0.3, 2.0], [-0.8, -0.4, 2.5], [0.0, 0.0, 1.0], [0.9, -0.45, 1.8]])


def _dots(camera: CameraModel) -> np.ndarray:
    """Image of small bright blobs where the points project through ``camera``."""
    px, _ = cv2.projectPoints(POINTS_CAM_M, np.zeros(3), np.zeros(3), camera.K, camera.dist)
    img = np.zeros((camera.height, camera.width, 3), np.uint8)
    for u, v in px.reshape(-1, 2):
        cv2.circle(img, (int(round(u * 16)), int(round(v * 16))), 4 * 16, (255, 255, 255), -1,
                   cv2.LINE_AA, 4)
    return img


def _centroids(image: np.ndarray) -> np.ndarray:
    grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY).astype(np.float64)
    n, labels = cv2.connectedComponents((grey > 20).astype(np.uint8))
    out = []
    for i in range(1, n):
        ys, xs = np.nonzero(labels == i)
        w = grey[ys, xs]
        out.append([np.sum(xs * w) / w.sum(), np.sum(ys * w) / w.sum()])
    return np.array(sorted(out))


def _expected(camera: CameraModel) -> np.ndarray:
    px, _ = cv2.projectPoints(POINTS_CAM_M, np.zeros(3), np.zeros(3), camera.K, camera.dist)
    return np.array(sorted(px.reshape(-1, 2).tolist()))


@pytest.mark.parametrize('undistort', [False, True])
def test_resize_and_undistort_keep_projections(undistort: bool) -> None:
    prep = ingest.FramePreparer(ingest.IngestConfig(max_width_px=640, undistort=undistort))
    assert prep.configure(CAM) and not prep.configure(CAM)
    out = prep.process(_dots(CAM))
    cam = prep.camera_out
    assert out.shape == (360, 640, 3) and (cam.width, cam.height) == (640, 360)
    assert cam.has_distortion is not undistort
    np.testing.assert_allclose(_centroids(out), _expected(cam), atol=0.35)


def test_size_change_reinitialises_and_mismatch_raises() -> None:
    prep = ingest.FramePreparer(ingest.IngestConfig(max_width_px=640))
    prep.configure(CAM)
    with pytest.raises(errors.MessageError):
        prep.process(np.zeros((480, 640, 3), np.uint8))
    assert prep.configure(CAM.resized(640, 360))
    assert prep.process(np.zeros((360, 640, 3), np.uint8)).shape == (360, 640, 3)
    with pytest.raises(ValueError):
        ingest.IngestConfig(max_width_px=8)


def test_calibration_yaml(tmp_path: Path) -> None:
    path = tmp_path / 'cam.yaml'
    path.write_text(
        'image_width: 1280\nimage_height: 720\ncamera_name: cam\n'
        f'camera_matrix: {{rows: 3, cols: 3, data: {CAM.K.ravel().tolist()}}}\n'
        'distortion_model: plumb_bob\n'
        f'distortion_coefficients: {{rows: 1, cols: 5, data: {CAM.dist.tolist()}}}\n')
    cam = calibration.load_calibration_yaml(path)
    assert (cam.width, cam.height, cam.distortion_model) == (1280, 720, 'plumb_bob')
    np.testing.assert_array_equal(cam.K, CAM.K)
    np.testing.assert_array_equal(cam.dist, CAM.dist)
    (tmp_path / 'bad.yaml').write_text('image_width: 3\n')
    with pytest.raises(errors.AbsScaleError):
        calibration.load_calibration_yaml(tmp_path / 'bad.yaml')


def test_gap_counter() -> None:
    gaps = ingest.GapCounter()
    stamps = [i * 33_333_333 for i in range(10)] + [12 * 33_333_333, 13 * 33_333_333]
    assert sum(gaps.add(s) for s in stamps) == 2 and gaps.missing == 2
