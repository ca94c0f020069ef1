"""Motion-blurred sheets (mid-level edges) and the aspect check with lens distortion."""
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from absscale_ros.core import detect, detect_sheet, sides

DATA = Path(__file__).parents[1] / 'data' / 'sim_blur'
FRAMES = json.loads((DATA / 'frames.json').read_text())['frames']


def _run(fr, with_dist=True):
    img = cv2.imread(str(DATA / fr['file']))
    return detect.detect(img, detect.DetectConfig(target=fr['target']), np.array(fr['K']),
                         np.array(fr['D']) if with_dist else None)


@pytest.mark.parametrize('fr', [f for f in FRAMES if f['covers_min_area']],
                         ids=lambda f: f['file'])
def test_sheet_under_a_long_motion_blur_streak(fr):
    assert fr['motion_blur_px'] > 60.0
    res = _run(fr)
    assert [d.target_type for d in res.detections] == ['sheet']
    found, true = res.detections[0].vertices_px, np.array(fr['vertices_px'])
    err = np.array([np.hypot(*(found - t).T).min() for t in true])
    side = np.hypot(*(true - np.roll(true, 1, axis=0)).T).min()
    assert err.max() < 0.03 * side  # 74-92 px streaks: within 2-3 px here


@pytest.mark.parametrize('fr', [f for f in FRAMES if not f['covers_min_area']],
                         ids=lambda f: f['file'])
def test_board_at_the_border_rejected_once_distortion_is_undone(fr):
    assert _run(fr).detections == ()


def test_ramp_width_of_a_box_blurred_step():
    img = np.full((200, 200, 3), 60, np.uint8)
    img[:, 100:] = 230
    blurred = cv2.blur(img, (21, 1))  # a 21 px streak across the vertical edge
    line = np.array([[-1.0, 0.0, 99.5]])  # x = 99.5, normal towards the dark side
    ends = np.array([[[99.5, 40.0], [99.5, 160.0]]])
    inside, outside = np.array([[230.0] * 3]), np.array([[60.0] * 3])
    sharp = sides.ramp_widths(img, line, ends, 30.0, inside, outside)
    wide = sides.ramp_widths(blurred, line, ends, 30.0, inside, outside)
    assert sharp[0] < 2.0 and 9.0 < wide[0] < 12.0  # half the streak


def test_ramp_width_along_a_rough_side_screens_sharp_outlines():
    """
    The blur retry's screen, on the rough side (3 px off, 2 degrees tilted) with the colours
    at its band's ends and samples ``blur_step`` apart: the blurred step still ramps over
    about half its streak, the sharp one under ``BLUR_MIN_RAMP_PX`` (not retried).
    """
    img = np.full((200, 200, 3), 60, np.uint8)
    img[:, 100:] = 230
    blurred = cv2.blur(img, (21, 1))
    tilt = np.deg2rad(2.0)
    line = np.array([[-np.cos(tilt), np.sin(tilt), 0.0]])
    line[0, 2] = -line[0, :2] @ np.array([102.5, 100.0])
    ends = np.array([[[102.5 - 60 * np.tan(tilt), 40.0], [102.5 + 60 * np.tan(tilt), 160.0]]])
    band = 60.0
    step = sides.blur_step(band)
    assert step > sides.STEP_PX
    sharp = sides.ramp_widths(img, line, ends, band, None, None, step_px=step)
    wide = sides.ramp_widths(blurred, line, ends, band, None, None, step_px=step)
    assert sharp[0] < detect_sheet.BLUR_MIN_RAMP_PX < 9.0 < wide[0] < 12.0
