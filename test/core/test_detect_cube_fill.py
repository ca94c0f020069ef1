"""A face of a detected cube that the quad search missed, outlined where the pose shows it."""
from pathlib import Path
import sys

import cv2
import numpy as np
import pytest

from absscale_ros.core import cube_fill, cube_geometry

sys.path.insert(0, str(Path(__file__).parent))
import sim_cube_frames  # noqa: E402


def _cubes(name, **kw):
    return sim_cube_frames.cubes('sim_cube_fill', name, **kw)


def _pixels(fr, colour, polys):
    """(true face mask, mask of ``polys`` of ``colour``), pixel centres inside, 1280 x 720."""
    truth = np.zeros((720, 1280), np.uint8)
    for face in fr['faces']:
        if face['colour'] == colour:
            cv2.fillPoly(truth, [np.asarray(p, np.int32) for p in face['polygons_px']], 1)
    found = np.zeros_like(truth)
    for p in polys:
        cv2.fillPoly(found, [np.round(np.asarray(p) * 16).astype(np.int32).reshape(-1, 1, 2)],
                     1, shift=4)
    return truth > 0, found > 0


def _scores(fr, det, colour):
    """(precision, recall) of the detection's outlines of ``colour`` against the true face."""
    truth, found = _pixels(fr, colour, [p for c, p in det.polygons if c == colour])
    tp = np.count_nonzero(truth & found)
    return tp / max(np.count_nonzero(found), 1), tp / np.count_nonzero(truth)


@pytest.mark.parametrize('name, colour, min_recall', [
    # A post in front leaves the red top five-sided, so the quad search finds no top; the cube
    # is found on its purple face and its yellow one (cut along the post).
    ('outdoor_cube_73_215.jpg', 'red', 0.92),
    # A yellow box behind the cube joins its yellow face in the mask: the region is no quad.
    # Inside the posed face only the face's own pixels are drawn, not the box's.
    ('outdoor_cube_4_175.jpg', 'yellow', 0.95)])
def test_face_the_quad_search_misses_is_outlined_where_the_pose_shows_it(
        name, colour, min_recall):
    fr, dets = _cubes(name)
    assert len(dets) == 1
    precision, recall = _scores(fr, dets[0], colour)
    assert precision > 0.98 and recall > min_recall, (precision, recall)
    # An outline only: the vertices are those found without it.
    bare = _cubes(name, fill_min_frac=0.0)[1]
    assert colour not in {c for c, _ in bare[0].polygons}
    np.testing.assert_array_equal(bare[0].vertices_px, dets[0].vertices_px)


def test_missing_faces_names_the_third_colour_from_two():
    # A cube posed on a square off the optical axis shows two of its sides as well.
    K = np.array([[800.0, 0.0, 640.0], [0.0, 800.0, 360.0], [0.0, 0.0, 1.0]])
    corners = np.array([[200.0, 100.0], [300.0, 100.0], [300.0, 200.0], [200.0, 200.0]])
    proj = cube_geometry.cube_projections(corners, K)[0]
    a, b = (np.asarray(s, float).reshape(-1, 2) for s in cube_geometry.shown_sides(proj))
    missing = cube_fill.missing_faces(proj, [('red', corners), ('yellow', a)])
    assert [c for c, _ in missing] == ['purple']
    assert np.abs(np.sort(missing[0][1], axis=0) - np.sort(b, axis=0)).max() < 1e-3
    # A strip along a side names its face too; one colour alone names neither of the others;
    # two colours on one pair: none.
    strip = np.array([a[0], a[0] + 0.1 * (a[3] - a[0]), a[1] + 0.1 * (a[2] - a[1]), a[1]])
    assert [c for c, _ in cube_fill.missing_faces(proj, [('red', corners), ('yellow', strip)])
            ] == ['purple']
    assert cube_fill.missing_faces(proj, [('red', corners)]) == []
    assert cube_fill.missing_faces(proj, [('red', corners), ('red', a)]) == []


def test_a_cube_posed_edge_on_shows_no_face_to_fill() -> None:
    # Every corner on one image line: no face has an area, so none is shown (no crash).
    proj = np.column_stack([np.linspace(100.0, 300.0, 8), np.full(8, 200.0)])
    assert cube_fill.missing_faces(proj, [('red', proj[:4])]) == []
