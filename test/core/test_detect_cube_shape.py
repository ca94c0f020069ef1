"""
The cube shape check on simulator frames where face corners are not cube vertices: a face cut
by a post, cube-coloured boxes against or behind the cube. No reported vertex may be off a true
one (a wrong vertex gives a wrong scale downstream); without the check each of these frames
reports vertices 15-300 px off. Two clear frames (a narrow side face, a cube seen square-on
under a thin top strip) must still give the cube.
"""
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from absscale_ros.core import detect, detect_cube

DATA = Path(__file__).parents[1] / 'data' / 'sim_frames'
FRAMES = json.loads((DATA / 'cube_shape.json').read_text())['frames']


def _errors(fr, found):
    """Per reported vertex: distance to the nearest visible true vertex, px."""
    true = np.array([v for v, vis in zip(fr['vertices_px'], fr['vertex_visible']) if vis])
    return np.array([np.hypot(*(true - v).T).min() for v in found])


def _relative_errors(fr, found):
    """Per reported vertex: that distance over the longest image edge at the true vertex."""
    v = np.array([p if p is not None else [np.nan, np.nan] for p in fr['vertices_px']], float)
    vis = np.flatnonzero(fr['vertex_visible'])
    out = []
    for p in found:
        i = vis[np.argmin(np.hypot(*(v[vis] - p).T))]
        ends = [b if a == i else a for a, b in fr['edges'] if i in (a, b)]
        length = np.nanmax([np.hypot(*(v[j] - v[i])) for j in ends])
        out.append(np.hypot(*(v[i] - p)) / length)
    return np.array(out)


@pytest.mark.parametrize('with_K', [True, False])
@pytest.mark.parametrize('fr', FRAMES, ids=lambda f: f['file'])
def test_no_vertex_off_the_cube(fr, with_K):
    img = cv2.imread(str(DATA / fr['file']))
    K = np.array(fr['K']) if with_K else None
    res = detect.detect(img, detect.DetectConfig(target='cube'), K)
    found = np.concatenate([d.vertices_px for d in res.detections] or [np.zeros((0, 2))])
    if len(found):  # a match, not a neighbour: the bench's 10% of the edge (paper's l)
        assert _relative_errors(fr, found).max() < 0.1, fr['what']
    # Frames the check must not lose: the uncut face of 4/57, and whole cubes.
    assert len(found) >= fr.get('min_found', 4 if fr['frame'] == 57 else 0), fr['what']


def test_check_off_reports_the_cut_corners():
    """The frames are hard cases: with the tolerance opened wide, wrong vertices come back."""
    loose = detect_cube.CubeConfig(shape_tol_frac=10.0)
    worst = []
    for fr in FRAMES:
        img = cv2.imread(str(DATA / fr['file']))
        for d in detect_cube.detect_cubes(img, loose, np.array(fr['K'])):
            worst.append(_errors(fr, d.vertices_px).max())
    assert max(worst) > 10.0
