"""Sheet aspect test with intrinsics: tight where the corners fix the ratio, loose elsewhere."""
import json
from pathlib import Path
import sys

import cv2
import numpy as np
import pytest

from absscale_ros.core import detect, detect_sheet, sheet_checks

sys.path.insert(0, str(Path(__file__).parent))
import synth_targets as st  # noqa: E402

DATA = Path(__file__).parents[1] / 'data' / 'sim_aspect'
FRAMES = json.loads((DATA / 'frames.json').read_text())['frames']
LETTER = detect_sheet.SheetConfig(sheet='letter')


@pytest.mark.parametrize('fr', FRAMES, ids=lambda f: f['file'])
def test_sim_white_board_of_other_aspect_is_not_a_sheet(fr):
    assert fr['sheet_area_fraction'] < 0.005  # the sheet itself is too small to report
    img = cv2.imread(str(DATA / fr['file']))
    res = detect.detect(img, detect.DetectConfig(target=fr['target']), np.array(fr['K']))
    assert res.detections == ()


def _letter_px(rvec, aspect=0.2794 / 0.2159, dist_m=0.8):
    return st.project_sheet(rvec, (0.0, 0.0, dist_m), size_m=(0.2159, 0.2159 * aspect))


def test_square_on_sheet_gets_the_floor_and_a_four_to_three_board_fails():
    letter, board = _letter_px((0.1, 0.05, 0.3)), _letter_px((0.1, 0.05, 0.3), aspect=4 / 3)
    tol = sheet_checks.aspect_tolerance(letter, LETTER, st.K)
    assert tol == LETTER.aspect_floor
    assert sheet_checks.aspect_error(letter, (st.H, st.W), LETTER, st.K) < 1e-6
    assert sheet_checks.aspect_error(board, (st.H, st.W), LETTER, st.K) > 0.025
    assert not sheet_checks.aspect_ok(board, (st.H, st.W), LETTER, st.K,
                                      sheet_checks.aspect_tolerance(board, LETTER, st.K))


def test_small_sheet_seen_edge_on_gets_a_wide_tolerance():
    far = _letter_px((1.35, 0.0, 0.2), dist_m=2.5)  # short side ~ 20 px
    tol = sheet_checks.aspect_tolerance(far, LETTER, st.K)
    assert tol == LETTER.aspect_tol  # capped
    near = _letter_px((0.9, 0.0, 0.2))
    assert LETTER.aspect_floor < sheet_checks.aspect_tolerance(near, LETTER, st.K) < tol
    # without intrinsics the focal length is unknown: the fixed tolerance
    assert sheet_checks.aspect_tolerance(near, LETTER, None) == LETTER.aspect_tol


def test_bad_aspect_floor_raises():
    with pytest.raises(ValueError):
        detect_sheet.SheetConfig(aspect_floor=0.2)


def test_corner_beyond_the_image_border_is_not_covered():
    img = np.full((100, 200, 3), 90, np.uint8)
    img[40:, 80:] = 240  # the whole column below differs from the sheet's colour
    inside = np.array([[90.0, 90.0, 90.0]] * 4)
    assert sheet_checks.covered(img, np.array([100.0, 60.0]), inside, LETTER)
    assert not sheet_checks.covered(img, np.array([100.0, -4.0]), inside, LETTER)
    assert not sheet_checks.covered(img, np.array([203.0, 60.0]), inside, LETTER)
