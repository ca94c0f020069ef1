"""Chessboard calibration recovers a known camera from a rendered video; YAML round trip."""
from pathlib import Path
import subprocess
import sys

from absscale_ros.core import calibration
from absscale_ros.core.errors import AbsScaleError, DegenerateGeometryError
from absscale_ros.core.types import CameraModel
import cv2
import numpy as np
import pytest

K_TRUE = np.array([[600.0, 0.0, 322.0], [0.0, 600.0, 236.0], [0.0, 0.0, 1.0]])
SIZE = (640, 480)


def _board_image(cols: int, rows: int, px: int) -> np.ndarray:
    """A printed chessboard with a white margin, ``px`` pixels per square."""
    squares = (np.indices((rows + 1, cols + 1)).sum(axis=0) % 2 == 0).astype(np.uint8) * 255
    img = cv2.resize(squares, ((cols + 1) * px, (rows + 1) * px), interpolation=cv2.INTER_NEAREST)
    return cv2.copyMakeBorder(img, px, px, px, px, cv2.BORDER_CONSTANT, value=255)


def _write_video(path: Path, frames: int = 24) -> None:
    """The board (9x6 inner corners, 25 mm squares) seen from varied poses by K_TRUE."""
    px = 40
    board = _board_image(9, 6, px)
    h, w = board.shape
    sq = 0.025 / px  # metres per board-image pixel
    # Board-image pixel -> board plane (m), origin at the first inner corner.
    A = np.array([[sq, 0, -2 * px * sq], [0, sq, -2 * px * sq], [0, 0, 1]])
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*'MJPG'), 10, SIZE)
    rng = np.random.default_rng(0)
    for i in range(frames):
        rvec = rng.uniform(-0.5, 0.5, 3)
        R, _ = cv2.Rodrigues(rvec)
        centre = np.array([0.1, 0.0625, 0.0])  # middle of the inner corners, board frame
        t = -R @ centre + np.array([0.0, 0.0, 0.45 + 0.1 * i / frames])
        H = K_TRUE @ np.column_stack([R[:, 0], R[:, 1], t]) @ A
        img = cv2.warpPerspective(board, H, SIZE, borderValue=128, flags=cv2.INTER_LINEAR)
        writer.write(cv2.cvtColor(img, cv2.COLOR_GRAY2BGR))
    writer.release()


def test_calibrate_command_recovers_focal_length(tmp_path: Path) -> None:
    video = tmp_path / 'board.avi'
    _write_video(video)
    out = tmp_path / 'cam.yaml'
    done = subprocess.run([sys.executable, '-m', 'absscale_ros.cli', 'calibrate', str(video),
                           '--board', '9x6', '--square', '0.025', '--every', '1', '--out',
                           str(out)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    model = calibration.model_from_yaml(out.read_text())
    assert (model.width, model.height) == SIZE
    assert model.K[0, 0] == pytest.approx(600.0, rel=0.01)
    assert model.K[0, 2] == pytest.approx(322.0, abs=4.0)


def test_yaml_round_trip_and_bad_file() -> None:
    model = CameraModel(1280, 720, K_TRUE, np.array([-0.1, 0.01, 0.0, 0.0, 0.0]), 'plumb_bob')
    back = calibration.model_from_yaml(calibration.model_to_yaml(model))
    assert np.allclose(back.K, model.K) and np.allclose(back.dist, model.dist)
    with pytest.raises(AbsScaleError, match='not a ROS calibration file'):
        calibration.model_from_yaml('image_width: 3\n', 'x.yaml')


def test_too_few_views_refused() -> None:
    with pytest.raises(DegenerateGeometryError, match='move the board'):
        calibration.calibrate([], SIZE, calibration.CalibrationConfig())
