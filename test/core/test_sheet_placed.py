"""A sheet under a box whose edge runs through the end of a whole side: no corner placed by the
sheet's aspect alone (``sheet_stub.finish``), against the renderer's ground truth."""
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from absscale_ros.core import detect

DATA = Path(__file__).parents[1] / 'data' / 'sim_placed'
FRAMES = json.loads((DATA / 'frames.json').read_text())['frames']


@pytest.mark.parametrize('fr', FRAMES, ids=lambda f: f['file'])
def test_no_sheet_corner_placed_off_by_the_aspect(fr):
    """
    Seed 86 frame 170 and seed 84 frame 180: the stub's edge was the box's, and the corner the
    aspect placed at the end of the whole side was 4.9 % and 3.2 % of the side off (the
    vanishing geometry of two short sides: a quarter of the side or more per pixel of side
    line). A sheet reported here has every corner within 1 % of its edge of the true one.
    """
    img = cv2.imread(str(DATA / fr['file']))
    res = detect.detect(img, detect.DetectConfig(target=fr['target']), np.array(fr['K']),
                        np.array(fr['D']))
    true = np.array([v if v is not None else [np.nan, np.nan] for v in fr['vertices_px']])
    edge = min(np.hypot(*(true[b] - true[a])) for a, b in fr['edges'])
    for d in res.detections:
        assert d.target_type == 'sheet'
        off = np.nanmin(np.hypot(*(d.vertices_px[:, None] - true[None]).T), axis=0)
        assert off.max() <= 0.01 * edge, off / edge
