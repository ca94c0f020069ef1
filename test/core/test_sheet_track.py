"""A rectangle of a nearby aspect, judged over the frames it is seen (``sheet_track``)."""
from dataclasses import replace
import json
from pathlib import Path

import numpy as np
import pytest

from absscale_ros import bagio, conversions
from absscale_ros.core import detect, sheet_track

BAG = str(Path(__file__).parents[2] / 'bags' / 'indoor_paper_sample.mcap')
SQUARE = np.array([[0.0, 0.0], [100.0, 0.0], [100.0, 80.0], [0.0, 80.0]])


def test_a_rectangle_that_fails_in_most_frames_is_refuted_when_it_passes():
    history = sheet_track.SheetHistory()
    for k, ratio in enumerate((1.3, 1.4, 0.9)):  # passes in the third frame only
        history.next_frame(20)
        quad = SQUARE + 5.0 * k  # a pan moves it a little from frame to frame
        history.note(quad, ratio)
        history.note(quad + 0.5, ratio + 0.2)  # another mask's outline: the smaller counts
    assert history.refuted(quad, 20, 2)
    assert not history.refuted(quad, 20, 3)  # measured in two earlier frames only
    history.next_frame(20)
    elsewhere = SQUARE + 300.0  # another rectangle: no history
    history.note(elsewhere, 0.9)
    assert not history.refuted(elsewhere, 20, 1)


def test_of_several_outlines_in_a_frame_the_smallest_error_counts():
    # Another mask's outline of the same rectangle passes in every frame: the rectangle is
    # not refuted, whichever of its outlines was measured first.
    for order in (1, -1):
        history = sheet_track.SheetHistory()
        for failing in (1.3, 1.4, 1.2):
            history.next_frame(20)
            for quad, ratio in [(SQUARE, failing), (SQUARE + 0.5, 0.6)][::order]:
                history.note(quad, ratio)
        assert not history.refuted(SQUARE, 20, 2), order


def test_only_the_window_is_kept():
    history = sheet_track.SheetHistory()
    for ratio in [1.5] * 30 + [0.5] * 3:  # refuted long ago, passing in the last frames
        history.next_frame(3)
        history.note(SQUARE, ratio)
    assert not history.refuted(SQUARE, 3, 2)
    assert len(history._tracks) == 1 and len(history._tracks[0].ratios) == 4


def test_a_rectangle_that_passes_in_most_frames_is_kept():
    history = sheet_track.SheetHistory()
    for ratio in (0.5, 1.2, 0.7, 0.8):
        history.next_frame(20)
        history.note(SQUARE, ratio)
    assert not history.refuted(SQUARE, 20, 2)


@pytest.mark.parametrize('line_candidates', [False, True])
def test_sample_wall_board_is_not_a_letter_over_the_frames_it_is_seen(line_candidates):
    # bags/indoor_paper_sample.mcap frames 68-78: the letter page is under the area test, a
    # 1.2 x 0.9 m board on the wall fails the aspect test in 68-77 (3 % off letter) and
    # passes in 78 (its corners 1.4 px off: 1.97 % against the 2 % floor). With the
    # straight-edge candidates, the board the masks' path refutes is found again there.
    gt = json.loads(Path(BAG + '.gt.json').read_text())
    K, dist = np.array(gt['camera']['K']), np.array(gt['camera']['D'])
    cfg = detect.DetectConfig(target='letter')
    cfg = replace(cfg, sheet=replace(cfg.sheet, line_candidates=line_candidates))
    history = sheet_track.SheetHistory()
    with bagio.open_bag(BAG) as reader:
        for k, raw in enumerate(reader.messages([gt['bag']['image_topic']])):
            if k < 68:
                continue
            img = conversions.compressed_msg_to_bgr(reader.deserialize(raw))
            res = detect.detect(img, cfg, K, dist, sheet_history=history)
            assert res.detections == ()
            if k == 78:
                break
    board = detect.detect(img, cfg, K, dist).detections  # the frame alone
    assert len(board) == 1 and gt['frames'][78]['targets'][0]['area_fraction'] < 0.005
