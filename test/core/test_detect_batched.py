"""The detectors' batched steps give what their one-candidate versions give, on rendered frames."""
import json
from pathlib import Path
import sys

import cv2
import numpy as np
import pytest

from absscale_ros.core import cube_occluder, detect, detect_cube, detect_sheet, lines, sides

sys.path.insert(0, str(Path(__file__).parent))
import synth_targets as st  # noqa: E402


def _quad_sides(quad, shift_px):
    """Rough (4, 3) lines and (4, 2, 2) ends of a quad pushed ``shift_px`` off its outline."""
    centre = quad.mean(axis=0)
    rough = np.array([lines.line_through(a, b, centre) for a, b in
                      zip(quad, np.roll(quad, -1, axis=0))])
    rough[:, 2] -= shift_px
    ends = np.stack([quad, np.roll(quad, -1, axis=0)], axis=1)
    return rough, ends


def test_refine_many_equals_one_call_per_candidate():
    true_px = st.project_sheet((0.4, -0.2, 0.3), (0.0, 0.0, 1.0))
    img = st.render_sheet(np.random.default_rng(3), true_px, blur_px=3)
    # The sheet with two profile counts, and a quad of empty desk that fails the first pass.
    empty = np.array([[40.0, 40.0], [200.0, 40.0], [200.0, 150.0], [40.0, 150.0]])
    cands = [_quad_sides(true_px, 2.5), _quad_sides(true_px, -1.5), _quad_sides(empty, 0.0)]
    ns = [16, 37, 20]
    batched = sides.refine_many(img, [c[0] for c in cands], [c[1] for c in cands],
                                (8.0, 4.0, 3.0), ns, 0.25)
    assert batched[2] is None and batched[0] is not None and batched[1] is not None
    for (rough, ends), n, got in zip(cands, ns, batched):
        alone = sides.refine_checked(img, rough, ends, (8.0, 4.0, 3.0), n, 0.25)
        assert (alone is None) == (got is None)
        for a, b in zip(alone or (), got or ()):
            np.testing.assert_allclose(a, b, atol=1e-9)
    corners = lines.quad_corners(list(batched[1][0]))
    assert np.abs(corners - true_px).max() < 0.5  # and right: the refined sheet's corners


def test_colour_masks_equal_one_mask_per_colour():
    R, t = st.cube_pose(30.0, 20.0, 5.0)
    img = st.render_cube(np.random.default_rng(2), R, t)[0]
    hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
    cfg = detect_cube.CubeConfig()
    masks = detect_cube.colour_masks(hsv, cfg)
    for colour, hue in cfg.hue_ranges().items():
        one = detect_cube.colour_mask(hsv, hue, cfg)
        assert np.count_nonzero(one) > 1000  # every face is seen
        np.testing.assert_array_equal(masks[colour], one)


def test_hough_lines_equal_one_vote_per_point_set():
    rng = np.random.default_rng(4)
    sets, thetas, rhos = [], [], []
    for _ in range(12):  # sides of several lengths, directions and offsets
        ang, length = rng.uniform(-np.pi, np.pi), rng.uniform(20.0, 400.0)
        d, p0 = np.array([np.cos(ang), np.sin(ang)]), rng.uniform(0.0, 1280.0, 2)
        u = np.linspace(0.0, length, int(length / 2))
        normal = np.array([-d[1], d[0]])
        sets.append(np.round(2.0 * (p0 + u[:, None] * d)) / 2.0)  # on a half-pixel grid
        thetas.append(np.arctan2(normal[1], normal[0]) + rng.normal(0.0, 0.05))
        rhos.append(float(p0 @ normal) + rng.normal(0.0, 2.0))
    batched = lines.hough_lines(sets, np.array(thetas), np.array(rhos))
    assert batched == [lines.hough_line(p, t, r) for p, t, r in zip(sets, thetas, rhos)]


def test_auto_mode_shares_the_half_size_image_without_changing_detections():
    R, t = st.cube_pose(35, 25, 5.0, offset_px=(-300, 0))

    def sheet(img):
        st.fill(img, st.sheet_corners((1000, 380), 220, aspect=279.4 / 215.9), (235, 238, 240))
    img = st.render_cube(np.random.default_rng(9), R, t, extra=sheet)[0]
    res = detect.detect(img, detect.DetectConfig(target='auto'))
    alone = (detect_cube.detect_cubes(img, detect_cube.CubeConfig())
             + detect_sheet.detect_sheets(img, detect_sheet.SheetConfig(sheet='letter')))
    assert [d.target_type for d in res.detections] == ['cube', 'sheet']
    for shared, own in zip(res.detections, alone):
        np.testing.assert_array_equal(shared.vertices_px, own.vertices_px)


SIM_FRAMES = Path(__file__).parents[1] / 'data' / 'sim_frames'


def test_candidate_search_in_two_steps_is_the_search_over_every_mask():
    """Whiteness masks first, colour edges on demand (``Candidates``): together they give the
    quads and regions of one search over every mask, in its order; a page that differs from
    the desk in tint only (a yellowish page on a grey desk as bright) comes from the edges."""
    from absscale_ros.core import sheet_candidates as sc
    cfg = detect_sheet.SheetConfig(sheet='a4')
    true_px = st.sheet_corners((640, 360), 300)
    tint = st.render_sheet(np.random.default_rng(5), true_px, paper_bgr=(170, 205, 215),
                           desk_bgr=(200, 200, 200))
    for img in [cv2.imread(str(SIM_FRAMES / n)) for n in
                ('indoor_paper_1_22.jpg', 'indoor_paper_4d_13.jpg')] + [tint]:
        work = sc.shrink(img, 480 / 1280)
        steps = sc.Candidates(work, cfg)
        n_white = len(steps.quads)
        added = steps.edge_quads()
        assert steps.edge_quads() == [] and len(steps.quads) == n_white + len(added)
        quads, regions = sc.candidates(work, cfg)
        assert len(quads) == len(steps.quads) and len(regions) == len(steps.regions)
        for a, b in zip(quads, steps.quads):
            np.testing.assert_array_equal(a, b)
        for (a, _), (b, _) in zip(regions, steps.regions):
            np.testing.assert_array_equal(a, b)
    true_work = (true_px + 0.5) * 480 / 1280 - 0.5
    assert not any(np.abs(q - true_work).max() < 3.0 for q in steps.quads[:n_white])
    assert any(np.abs(np.roll(q, k, axis=0) - true_work).max() < 3.0
               for q in added for k in range(4))


def test_sheet_found_by_whiteness_skips_the_colour_edges(monkeypatch):
    """A sheet the whiteness masks outline is found without the colour Canny (a third of the
    candidate search); a frame without a sheet still searches the edges."""
    from absscale_ros.core import sheet_candidates as sc
    calls = []
    edge_masks = sc.edge_masks
    monkeypatch.setattr(sc, 'edge_masks', lambda *a: calls.append(1) or edge_masks(*a))
    fr = {f['file']: f for f in json.loads((SIM_FRAMES / 'frames.json').read_text())['frames']}
    for name, searched in (('indoor_paper_1_22.jpg', []), ('indoor_paper_2_07.jpg', [1])):
        calls.clear()
        img = cv2.imread(str(SIM_FRAMES / name))
        dets = detect_sheet.detect_sheets(img, detect_sheet.SheetConfig(sheet=fr[name]['target']),
                                          np.array(fr[name]['K']))
        assert len(dets) == int(not searched) and calls == searched, name


def test_whole_sheet_too_small_is_not_retried_with_a_hidden_corner(monkeypatch):
    """A whole sheet refined on all four sides but under the 0.5 % area: its region would give
    the hidden-corner paths only the same too small seen part, so none of them refine it."""
    from absscale_ros.core import sheet_stub
    true_px = st.sheet_corners((500, 300), 55, aspect=279.4 / 215.9)  # 0.42 % of the image
    img = st.render_sheet(np.random.default_rng(2), true_px)
    regions = []
    first = sheet_stub.first_hypotheses
    monkeypatch.setattr(sheet_stub, 'first_hypotheses',
                        lambda r, *a: regions.append(len(r)) or first(r, *a))
    assert detect_sheet.detect_sheets(img, detect_sheet.SheetConfig(sheet='letter')) == []
    assert regions == [0, 0]  # (convex regions, then notched ones: none of either)
    monkeypatch.setattr(detect_sheet, '_whole_small', lambda *a: False)
    assert detect_sheet.detect_sheets(img, detect_sheet.SheetConfig(sheet='letter')) == []
    assert regions[2] > 0  # without the test they would


def _cut_frame_faces():
    """The refined faces of a rendered frame where a post cuts the yellow face, its image."""
    img = cv2.imread(str(Path(__file__).parents[1] / 'data' / 'sim_cube_cut' /
                         'outdoor_cube_72_200.jpg'))
    return img, detect_cube.detect_faces(img, detect_cube.CubeConfig())


def test_occluder_sides_of_all_faces_equal_one_call_per_face():
    img, faces = _cut_frame_faces()
    assert len(faces) >= 2
    ls = np.stack([f.lines for f in faces])
    corners = np.stack([f.corners_px for f in faces])
    ends = np.stack([corners, corners[:, [1, 2, 3, 0]]], axis=2).reshape(-1, 2, 2)
    outside = sides.refine(img, ls.reshape(-1, 3), ends, (6.0,), 16)[4].reshape(-1, 4, 3)
    batched = cube_occluder.occluder_sides_many(img, ls, corners, outside, 15.0)
    alone = [cube_occluder.occluder_sides(img, f.lines, f.corners_px, o, 15.0)
             for f, o in zip(faces, outside)]
    np.testing.assert_array_equal(batched, np.array(alone))
    assert batched.any()  # the post's edge, found in the batch too


@pytest.mark.parametrize('stacked', [True, False])
def test_nearest_points_equal_one_solve_per_vertex(monkeypatch, stacked: bool):
    # Corners of the rendered faces: two lines each, and where faces meet four or six.
    _, faces = _cut_frame_faces()
    groups = [np.array([f.lines[c - 1], f.lines[c]]) for f in faces for c in range(4)]
    pts = np.array([f.corners_px[c] for f in faces for c in range(4)])
    near = np.hypot(*(pts[:, None] - pts[None]).transpose(2, 0, 1)) < 6.0
    merged = [np.concatenate([groups[j] for j in np.flatnonzero(row)]) for row in near]
    assert {len(g) for g in merged} >= {2, 4}
    sets = groups + merged
    if not stacked:  # a numpy without the private gufunc: the per-set fallback
        monkeypatch.setattr(lines, '_umath_linalg', None)
    got = lines.nearest_points(sets)
    np.testing.assert_array_equal(got, np.array([lines.nearest_point(g) for g in sets]))
    assert np.abs(got[:len(groups)] - pts).max() < 1e-6  # two lines: their crossing
