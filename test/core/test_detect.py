"""Detector tests on rendered frames (synthetic, anti-aliased, JPEG) and on real photographs."""
import csv
import json
from dataclasses import replace
from pathlib import Path
import sys

import cv2
import numpy as np
import pytest

from absscale_ros.core import (detect, detect_cube, detect_sheet, lines, quads, sheet_candidates,
                               sheet_checks, targets)

sys.path.insert(0, str(Path(__file__).parent))
import synth_targets as st  # noqa: E402

SMARTDOC = Path(__file__).parents[1] / 'data' / 'smartdoc15'
VARIANTS = Path(__file__).parents[1] / 'data' / 'smartdoc15_variants'


def _rng(seed=0):
    return np.random.default_rng(seed)


def _sheet_errors(det, true_px):
    """Corner errors px for the best cyclic shift, and the paper's delta / l."""
    best = min((np.roll(det.vertices_px, k, axis=0) for k in range(4)),
               key=lambda v: float(np.hypot(*(v - true_px).T).sum()))
    err = np.hypot(*(best - true_px).T)
    sides = np.hypot(*(true_px - np.roll(true_px, -1, 0)).T)
    return err, err / np.maximum(sides, np.roll(sides, 1))


# ---- lines ----------------------------------------------------------------------------------

def test_nearest_point_of_three_lines_meeting_at_a_point():
    p = np.array([10.0, -3.0])
    ls = []
    for ang in (0.1, 1.2, 2.5):
        n = np.array([np.cos(ang), np.sin(ang)])
        ls.append([n[0], n[1], -n @ p])
    assert np.allclose(lines.nearest_point(np.array(ls)), p)


def test_hough_line_recovers_a_slightly_curved_edge():
    u = np.linspace(0, 200, 400)
    pts = np.stack([u, 50 + 0.1 * u + 1e-4 * (u - 100) ** 2], axis=1)  # gentle bow
    theta, rho = lines.hough_line(pts, np.arctan2(1, -0.1) + 0.05, 50.0)
    n = np.array([np.cos(theta), np.sin(theta)])
    assert np.median(np.abs(pts @ n - rho)) < 1.5


# ---- sheet ----------------------------------------------------------------------------------

@pytest.mark.parametrize('rvec,blur', [((0.1, 0.0, 0.2), 0), ((0.6, -0.3, -0.4), 0),
                                       ((-0.5, 0.4, 0.7), 9)])
def test_sheet_corners_subpixel(rvec, blur):
    true_px = st.project_sheet(rvec, (0.05, 0.0, 1.0))
    img = st.render_sheet(_rng(1), true_px, blur_px=blur)
    dets = detect_sheet.detect_sheets(img, detect_sheet.SheetConfig(sheet='a4'))
    assert len(dets) == 1
    err, rel = _sheet_errors(dets[0], true_px)
    assert np.median(rel) < 0.005 and err.max() < (2.0 if blur else 1.0)
    assert list(dets[0].vertex_ids) == [0, 1, 2, 3]
    v = dets[0].vertices_px  # clockwise on screen from the smallest u + v
    assert np.argmin(v.sum(1)) == 0
    d1, d2 = v[1] - v[0], v[2] - v[1]
    assert d1[0] * d2[1] - d1[1] * d2[0] > 0  # y down: positive cross is clockwise


def test_sheet_with_distractors_wrong_aspect_and_dark_square():
    true_px = st.sheet_corners(centre_px=(400, 360), width_px=260)

    def extra(img):
        st.fill(img, st.sheet_corners((950, 300), 200, aspect=1.0), (235, 238, 240))  # square
        st.fill(img, st.sheet_corners((1000, 560), 150, aspect=3.0, angle_deg=80),
                (230, 230, 230))  # long strip
    img = st.render_sheet(_rng(2), true_px, extra=extra)
    dets = detect_sheet.detect_sheets(img, detect_sheet.SheetConfig(sheet='a4'))
    assert len(dets) == 1
    assert _sheet_errors(dets[0], true_px)[0].max() < 1.0


def test_sheet_partly_occluded_still_found():
    true_px = st.sheet_corners(width_px=320, angle_deg=5)

    def extra(img):  # a pen across one side
        st.fill(img, [[540, 420], [760, 300], [768, 312], [548, 432]], (30, 30, 30))
    img = st.render_sheet(_rng(3), true_px, extra=extra)
    dets = detect_sheet.detect_sheets(img, detect_sheet.SheetConfig(sheet='a4'))
    assert len(dets) == 1
    assert np.median(_sheet_errors(dets[0], true_px)[1]) < 0.005


@pytest.mark.parametrize('box', [
    [[680, 500], [800, 470], [830, 640], [700, 660]],  # covers the bottom right corner
    [[700, 100], [900, 100], [900, 300], [700, 300]]])  # covers the top right corner
def test_sheet_with_one_hidden_corner_extrapolated_and_marked(box):
    true_px = st.sheet_corners(width_px=320, angle_deg=5)

    def extra(img):  # a box on the sheet hides one corner
        st.fill(img, box, (50, 60, 40))
    img = st.render_sheet(_rng(3), true_px, extra=extra)
    dets = detect_sheet.detect_sheets(img, detect_sheet.SheetConfig(sheet='a4'))
    assert len(dets) == 1
    d = dets[0]
    hidden = [i for i, p in enumerate(true_px)
              if cv2.pointPolygonTest(np.float32(box), (float(p[0]), float(p[1])), False) > 0]
    assert len(hidden) == 1
    err, rel = _sheet_errors(d, true_px)
    seen = np.delete(err, hidden)
    assert seen.max() < 1.0  # the three seen corners as exact as a whole sheet's
    assert rel.max() < 0.02  # the extrapolated one: where its two sides meet
    scores = d.scores()
    far = int(np.argmax(np.hypot(*(d.vertices_px - true_px[hidden[0]]).T) < 10.0))
    assert scores[far] <= 0.5 < np.delete(scores, far).min() and d.score < 1.0
    seen_poly = d.polygons[0][1]  # the outline reported is the seen part only
    assert cv2.pointPolygonTest(seen_poly.astype(np.float32),
                                tuple(float(x) for x in true_px[hidden[0]]), False) < 0
    # Switched off (both hidden-corner paths), the sheet is not reported at all.
    off = detect_sheet.SheetConfig(sheet='a4', min_seen=1.0, stub_px=0.0)
    assert detect_sheet.detect_sheets(img, off) == []


@pytest.mark.parametrize('rvec,hidden,seen_px', [((0.5, -0.2, 0.3), 2, 15.0),
                                                 ((-0.4, 0.3, -0.6), 1, 15.0),
                                                 ((0.5, -0.2, 0.3), 2, 1.0)])
def test_sheet_with_corner_and_nearly_all_of_one_side_hidden(rvec, hidden, seen_px):
    """
    A box covers one corner and all but 15 px of one side next to it: the three seen corners
    come from the sides' edges, the hidden one from the intrinsics (``sheet_stub``). With
    1 px seen, the box's edge runs through the third corner: no sheet (that corner would be
    the sheet's aspect's alone, a quarter of the side or more off per pixel of side line;
    on rendered pages under a box 0.9 % of the side off in the median, up to 6 %).
    """
    true_px = st.project_sheet(rvec, (0.0, 0.0, 0.9))
    prev, corner, nxt = (true_px[(hidden + d) % 4] for d in (-1, 0, 1))
    stub = prev + seen_px * (corner - prev) / np.hypot(*(corner - prev))  # of that side
    part = nxt + 0.45 * (corner - nxt)  # a good part of the other one seen
    out = corner - true_px.mean(axis=0)
    box = [stub, stub + out, corner + out, part + out, part]

    def extra(img):
        st.fill(img, box, (40, 70, 120))
    img = st.render_sheet(_rng(13), true_px, extra=extra)
    dets = detect_sheet.detect_sheets(img, detect_sheet.SheetConfig(sheet='a4'), st.K)
    if seen_px < 2.0:
        assert dets == []
        return
    assert len(dets) == 1
    err, rel = _sheet_errors(dets[0], true_px)
    assert np.delete(err, hidden).max() < 1.0  # seen corners as exact as a whole sheet's
    assert rel[hidden] < 0.02
    d = dets[0]
    far = int(np.argmin(np.hypot(*(d.vertices_px - true_px[hidden]).T)))
    assert d.scores()[far] <= 0.5 < np.delete(d.scores(), far).min()
    # The pentagon rule alone cannot: one side at the hidden corner is seen over 15 px only.
    off = detect_sheet.SheetConfig(sheet='a4', stub_px=0.0)
    assert detect_sheet.detect_sheets(img, off, st.K) == []


def test_floor_tile_between_grout_lines_is_not_a_sheet():
    """Light tiles of the sheet's aspect: each outline is a dark line with tile beyond it."""
    rng = _rng(5)
    img = st._background(rng, (70, 75, 80))  # grout

    def tiles(img):
        for r in range(-1, 4):
            for c in range(-1, 6):
                shade = 190 + 30 * ((r + c) % 2)
                st.fill(img, st.sheet_corners((100 + 228 * c, 80 + 319 * r), 220,
                                              aspect=297.0 / 210.0, angle_deg=0),
                        (shade, shade + 2, shade + 4))
    tiles(img)
    img = st._finish(img, rng)
    cfg = detect_sheet.SheetConfig(sheet='a4')
    assert detect_sheet.detect_sheets(img, cfg) == []
    assert detect_sheet.detect_sheets(img, detect_sheet.SheetConfig(sheet='a4', max_ridges=4))


def test_sheet_smaller_than_area_threshold_rejected():
    # 0.005 * 1280 * 720 = 4608 px; a 50 x 71 px sheet is 3550 px.
    img = st.render_sheet(_rng(4), st.sheet_corners(width_px=50))
    assert detect_sheet.detect_sheets(img, detect_sheet.SheetConfig(sheet='a4')) == []
    img = st.render_sheet(_rng(4), st.sheet_corners(width_px=70))  # 70 x 99: kept
    assert len(detect_sheet.detect_sheets(img, detect_sheet.SheetConfig(sheet='a4'))) == 1


def test_rectangle_aspect_under_perspective():
    K = st.K
    w, h = 0.21, 0.297
    obj = np.array([[0, 0, 0], [w, 0, 0], [w, h, 0], [0, h, 0]])
    rvec = np.array([0.7, -0.3, 0.2])
    img_pts, _ = cv2.projectPoints(obj, rvec, np.array([-0.1, -0.1, 0.8]), K, None)
    aspect = lines.rectangle_aspect(img_pts.reshape(4, 2), K, 0.0, K[:2, 2])
    assert aspect == pytest.approx(h / w, rel=1e-6)
    est = lines.rectangle_aspect(img_pts.reshape(4, 2), None, 1000.0, K[:2, 2])
    assert est == pytest.approx(h / w, rel=0.02)


def _smartdoc():
    with open(SMARTDOC / 'ground_truth.csv') as f:
        for row in csv.DictReader(f):
            img = cv2.imread(str(SMARTDOC / 'frames' / row['image_path'].replace('/', '_')))
            yield row, img, np.array([[float(row[k + '_x']), float(row[k + '_y'])]
                                      for k in ('tl', 'tr', 'br', 'bl')])


def _real_figures(find):
    rels, found = [], 0
    for _, img, true_px in _smartdoc():
        dets = find(img)
        if dets:
            found += 1
            rels += list(min((_sheet_errors(d, true_px)[1] for d in dets),
                             key=lambda r: r.mean()))
    return found, rels


def test_real_smartdoc_frames():
    """Real A4 photographs (SmartDoc 2015, CC BY 4.0) with hand-annotated corners."""
    cfg = detect_sheet.SheetConfig(sheet='a4')
    found, rels = _real_figures(lambda img: detect_sheet.detect_sheets(img, cfg))
    # The two cluttered background05 frames (the page on other pages of the same white, a
    # cable and pens across its sides) are not found: see the issue 4 report.
    assert found >= 4
    assert np.median(rels) <= 0.005


def _shadowed(img, true_px, kind):
    """A real frame with a shadow cast across the page: half of it, or one corner."""
    h, w = img.shape[:2]
    yy, xx = np.mgrid[:h, :w]
    if kind == 'half':  # a hard shadow edge through the page's middle
        shade = (xx < true_px[:, 0].mean()).astype(np.float32)
    else:  # a soft-edged shadow over the top corner and parts of both its sides
        c = true_px[np.argmin(true_px[:, 1])]
        shade = (np.hypot(xx - c[0], yy - c[1]) < 0.35 * np.ptp(true_px[:, 1]))
        shade = cv2.GaussianBlur(shade.astype(np.float32), (0, 0), 5)
    return np.clip(img * (1.0 - 0.4 * shade[..., None]), 0, 255).astype(np.uint8)


@pytest.mark.parametrize('kind', ['half', 'corner'])
def test_real_smartdoc_frames_with_a_shadow_across_the_page(kind):
    """
    A shadow darkens the page and the desk alike: one surface each, in light and shade. (As
    ``absscale detect`` runs on photographs: a shadow edge splits the page's region masks,
    the straight-edge hypotheses still see four sides.)
    """
    cfg = detect_sheet.SheetConfig(sheet='a4', line_candidates=True)
    rels = []
    for row, img, true_px in _smartdoc():
        if row['bg_name'] == 'background05':
            continue  # not found unshadowed either
        dets = detect_sheet.detect_sheets(_shadowed(img, true_px, kind), cfg)
        assert len(dets) == 1, row['image_path']
        rels += list(_sheet_errors(dets[0], true_px)[1])
    assert np.median(rels) <= 0.005 and max(rels) < 0.012
    off = replace(cfg, max_shade=1.0)  # the colours compared as they are
    _, img, true_px = next(_smartdoc())
    assert detect_sheet.detect_sheets(_shadowed(img, true_px, kind), off) == []


def test_real_smartdoc_frames_cropped_off_centre():
    """
    The frames cropped 40 px left of and 30 px above the page: the principal point is no
    longer at the image centre, the focal length a larger fraction of the image, and no
    intrinsics are given. The aspect check tries a range of focal lengths (the one estimated
    from the page's own vanishing points measured these pages 9-23 % off A4).
    """
    cfg = detect_sheet.SheetConfig(sheet='a4')
    rels = []
    for row, img, true_px in _smartdoc():
        if row['bg_name'] == 'background05':
            continue  # not found uncropped either
        x0, y0 = (true_px.min(axis=0) - (40, 30)).astype(int)
        dets = detect_sheet.detect_sheets(img[y0:, x0:].copy(), cfg)
        assert len(dets) == 1, row['image_path']
        rels += list(_sheet_errors(dets[0], true_px - (x0, y0))[1])
    assert np.median(rels) <= 0.005


def test_real_smartdoc_frames_line_hypotheses_alone():
    """The straight-edge quadrilaterals find the same pages without any region mask."""
    cfg = detect_sheet.SheetConfig(sheet='a4')

    def lines_only(img):
        found = []
        for quad, band in detect_sheet._line_candidates(img, cfg):
            detect_sheet._accept(img, quad, band, cfg, None, found)
        return [detect_sheet._detection(f, cfg.model()) for f in found]
    found, rels = _real_figures(lines_only)
    assert found >= 4
    assert np.median(rels) <= 0.005


@pytest.mark.parametrize('width_px', [20, 45])
def test_real_smartdoc_page_next_to_a_dark_band_not_stretched_over_it(width_px):
    """
    A dark band (a magazine's edge) along the page's top side, bright desk beyond it: the
    quadrilateral whose top side is the band's far edge has a page-like colour inside its
    other three sides and a shadow-like one inside the fourth. It was reported (datasheet001:
    as the only sheet at 45 px, corners 46 px off); a page is never darker than its surface.
    """
    cfg = detect_sheet.SheetConfig(sheet='a4', line_candidates=True)
    for row, img, true_px in _smartdoc():
        if row['bg_name'] == 'background05':
            continue  # not found unchanged either
        up = true_px[0] - true_px[3]
        up /= np.linalg.norm(up)
        band = np.array([true_px[0], true_px[1], true_px[1] + width_px * up,
                         true_px[0] + width_px * up])
        beyond = band + np.array([0, 0, 120, 120])[:, None] * up + \
            np.array([width_px, width_px, 0, 0])[:, None] * up
        for poly, bgr in ((beyond, (210, 200, 205)), (band, (95, 65, 95))):
            cv2.fillConvexPoly(img, np.round(poly * 16).astype(np.int32), bgr, cv2.LINE_AA, 4)
        dets = detect_sheet.detect_sheets(img, cfg)
        assert len(dets) == 1, row['image_path']
        assert _sheet_errors(dets[0], true_px)[1].max() < 0.012, row['image_path']
        refined = detect_sheet.refine_quad(img, dets[0].vertices_px + up * width_px
                                           * np.array([1, 1, 0, 0])[:, None], 6.0)
        off = replace(cfg, min_inside_ratio=0.0)
        assert refined is not None and sheet_checks.passes(img, refined, off, None) and \
            not sheet_checks.passes(img, refined, cfg, None), row['image_path']


def test_real_smartdoc_variants_on_textured_desks():
    """
    SmartDoc pages re-photographed (``make_variants.py``): a camera rotation, desk texture
    touching the page, blur, JPEG. Each page is found to 0.5 % of its edge (the whiteness
    masks join it to bright texture: its own colour, masks opened to cut the texture off, LSD
    lines find it; 079 and 070 only the lines of the image without its text, the one beside a
    dark band is not stretched over the band).
    """
    with open(VARIANTS / 'gt.json') as f:
        gts = json.load(f)
    cfg = detect.DetectConfig(target='a4',
                              sheet=detect_sheet.SheetConfig(line_candidates=True))
    rels = []
    for name, gt in gts.items():
        true_px = np.array(gt['corners'])
        dets = detect.detect(cv2.imread(str(VARIANTS / name)), cfg).detections
        assert len(dets) == 1, name
        rel = _sheet_errors(dets[0], true_px)[1]
        assert rel.max() < 0.012, name  # (111: motion blur 11 px long, 0.6 % median)
        rels += list(rel)
    assert np.median(rels) <= 0.005


def test_real_pages_on_textured_desks_found_once_their_text_is_closed_away():
    """
    Two variants whose page the line search misses on the image as it is (its text lines and
    the desk's grain outvote its sides) and finds on the image with thin dark strokes closed
    away (``content_close_px``), refined on the image as it is.
    """
    with open(VARIANTS / 'gt.json') as f:
        gts = json.load(f)
    cfg = detect_sheet.SheetConfig(sheet='a4', line_candidates=True)
    for name in ('seed1_079_letter001.jpg', 'seed2_070_patent001.jpg'):
        img, true_px = cv2.imread(str(VARIANTS / name)), np.array(gts[name]['corners'])
        assert detect_sheet.detect_sheets(img, replace(cfg, content_close_px=0)) == [], name
        dets = detect_sheet.detect_sheets(img, cfg)
        assert len(dets) == 1 and _sheet_errors(dets[0], true_px)[1].max() < 0.007, name


def test_real_pages_on_a_light_wood_desk_outlined_by_their_chroma():
    """
    On the light wood desk (background01) no whiteness threshold separates the page from the
    desk; its blue-yellow chroma (b*) does, within a few work px of the annotated corners.
    """
    cfg = detect_sheet.SheetConfig(sheet='a4', line_candidates=True)
    for row, img, true_px in _smartdoc():
        if row['bg_name'] != 'background01':
            continue
        work = sheet_candidates.shrink(img, 0.25, None)

        def off(qs):
            return min((np.abs(np.roll(lines.full_px(q, 0.25), k, 0) - true_px).max()
                        for q in qs for k in range(4)), default=np.inf)
        assert off(sheet_candidates.Candidates(work, cfg).quads) > 100.0, row['image_path']
        assert off(sheet_candidates.chroma_quads(work, cfg)) < 12.0, row['image_path']


def test_segment_lines_follow_real_page_sides():
    """LSD lines (added to the Hough peaks) lie along all four sides of the real pages."""
    for row, img, true_px in _smartdoc():
        if row['bg_name'] == 'background05':
            continue  # its sides show an edge along 10-58 % of their length
        work = cv2.resize(img, (320, 180), interpolation=cv2.INTER_AREA)
        px = (true_px + 0.5) / 6.0 - 0.5
        ls = quads.segment_lines(work, quads.QuadConfig(min_side_px=20.0, segment_lines=40))
        for a, b in zip(px, np.roll(px, -1, axis=0)):
            dist = np.abs(ls[:, :2] @ np.stack([a, b]).T + ls[:, 2:3]).max(axis=1)
            assert dist.min() < 1.5, row['image_path']


def test_page_on_pages_of_the_same_white_found_by_its_edges():
    """A page on two other pages: one white blob to the masks, four straight sides to lines."""
    true_px = st.sheet_corners(centre_px=(640, 360), width_px=300, angle_deg=8)

    def under(img):
        for dx, dy, ang in ((40, 25, 2), (-30, 35, 14)):
            st.fill(img, st.sheet_corners((640 + dx, 360 + dy), 300, angle_deg=ang),
                    (212, 216, 220))
        st.fill(img, true_px, (236, 239, 241))
        st.fill(img, [[420, 300], [860, 460], [866, 448], [426, 288]], (25, 25, 25))  # a cable
    img = st.render_sheet(_rng(11), np.zeros((4, 2)) + 5.0, desk_bgr=(150, 170, 190),
                          extra=under)
    assert detect_sheet.detect_sheets(img, detect_sheet.SheetConfig(sheet='a4')) == []
    cfg = detect_sheet.SheetConfig(sheet='a4', line_candidates=True)
    dets = detect_sheet.detect_sheets(img, cfg)
    assert len(dets) >= 1
    rel = min((_sheet_errors(d, true_px)[1] for d in dets), key=lambda r: r.mean())
    assert np.median(rel) < 0.005


def test_quad_hypotheses_need_support_on_all_four_sides():
    img = st.render_sheet(_rng(12), st.sheet_corners(width_px=300))
    work = cv2.resize(img, (320, 180), interpolation=cv2.INTER_AREA)
    hyps, sup = quads.find_quads(work, quads.QuadConfig(min_side_px=15.0))
    assert len(hyps) >= 1 and sup.min() >= 0.7
    img[:, 640:] = img[:, 630:631]  # erase the right half: no closed outline left
    work = cv2.resize(img, (320, 180), interpolation=cv2.INTER_AREA)
    assert len(quads.find_quads(work, quads.QuadConfig(min_side_px=15.0))[0]) == 0


# ---- cube -----------------------------------------------------------------------------------

def _cube_errors(det, v_px, faces):
    vis = sorted({i for f in faces for i in f[2]})
    return np.array([np.hypot(*(v_px[vis] - v).T).min() for v in det.vertices_px])


@pytest.mark.parametrize('yaw,pitch,dist,blur', [(35, 25, 5.0, 0), (60, 30, 4.0, 0),
                                                 (45, 40, 3.0, 0), (35, 25, 5.0, 9)])
def test_cube_vertices_ids_and_edges(yaw, pitch, dist, blur):
    R, t = st.cube_pose(yaw, pitch, dist)
    img, faces, v_px = st.render_cube(_rng(5), R, t, blur_px=blur)
    dets = detect_cube.detect_cubes(img, detect_cube.CubeConfig())
    assert len(dets) == 1
    d = dets[0]
    err = _cube_errors(d, v_px, faces)
    assert np.median(err) < (1.0 if blur else 0.5) and err.max() < (2.5 if blur else 1.0)
    assert len(d.vertices_px) == 7 and len(d.edges) == 9
    assert sorted(targets.colour_mask(i) for i in d.vertex_ids) == [1, 2, 3, 4, 5, 6, 7]
    assert len(set(d.vertex_ids.tolist())) == len(d.vertex_ids)
    assert {c for c, _ in d.polygons} == {'red', 'yellow', 'purple'}


@pytest.mark.parametrize('yaw,pitch,offset', [(13.0, 25.0, (-300, 0)), (35.0, 22.0, (0, -250))])
def test_cube_with_one_face_seen_edge_on(yaw, pitch, offset):
    """A face almost edge-on (~6 px wide): found as a strip, its far corners not reported."""
    R, t = st.cube_pose(yaw, pitch, 5.0, offset)
    img, faces, v_px = st.render_cube(_rng(6), R, t)
    widths = [cv2.contourArea(p.astype(np.float32)) / max(np.hypot(*(p - np.roll(p, -1, 0)).T))
              for _, p, _ in faces]
    thin = [c for (c, _, _), w in zip(faces, widths) if w < 8.0]
    assert len(thin) == 1  # too thin for the mask stage
    dets = detect_cube.detect_cubes(img, detect_cube.CubeConfig())
    assert len(dets) == 1
    d = dets[0]
    # Every reported vertex is a true one; the one where the thin face's two far edges meet
    # the two big faces is ambiguous by the thin face's width (as without the strip).
    err = np.sort(_cube_errors(d, v_px, faces))
    assert err[-2] < 0.5 and err[-1] < 3.0
    assert thin[0] in {c for c, _ in d.polygons} and len(d.vertices_px) == 6
    bit = targets.COLOUR_BITS[thin[0]]  # the strip's colour names the corners it shares
    assert sum(bool(targets.colour_mask(i) & bit) for i in d.vertex_ids) >= 2
    # (the pose would show it too: ``cube_fill`` off as well)
    off = detect_cube.CubeConfig(strip_max_px=0.0, fill_min_frac=0.0)
    assert all(thin[0] not in {c for c, _ in x.polygons}
               for x in detect_cube.detect_cubes(img, off))


def test_cube_with_distractors_and_occlusion():
    R, t = st.cube_pose(35, 25, 5.0, offset_px=(-250, 0))

    def extra(img):  # a lone red board, a yellow disc, a purple L shape
        st.fill(img, [[900, 100], [1100, 110], [1090, 260], [905, 250]], (40, 35, 210))
        cv2.circle(img, (1000 * st.SS, 500 * st.SS), 80 * st.SS, (40, 205, 225), -1)
        st.fill(img, [[800, 550], [1000, 550], [1000, 580], [800, 580]], (170, 50, 140))
        st.fill(img, [[800, 550], [830, 550], [830, 700], [800, 700]], (170, 50, 140))
    img, faces, v_px = st.render_cube(_rng(6), R, t, extra=extra,
                                      occluder=[[300, 420], [330, 420], [330, 600], [300, 600]])
    dets = detect_cube.detect_cubes(img, detect_cube.CubeConfig())
    assert len(dets) == 1
    assert np.median(_cube_errors(dets[0], v_px, faces)) < 0.5


def test_cube_smaller_than_area_threshold_rejected():
    R, t = st.cube_pose(35, 25, 14.0)  # faces ~ 0.2% of the image
    img, _, _ = st.render_cube(_rng(7), R, t)
    assert detect_cube.detect_cubes(img, detect_cube.CubeConfig()) == []


def test_no_target_no_vertices():
    img = st.render_sheet(_rng(8), np.zeros((4, 2)) + 5.0)  # degenerate: nothing drawn
    assert detect.detect(img, detect.DetectConfig()).detections == ()


def test_auto_mode_reports_both_kinds():
    R, t = st.cube_pose(35, 25, 5.0, offset_px=(-300, 0))

    def sheet(img):
        st.fill(img, st.sheet_corners((1000, 380), 220, aspect=279.4 / 215.9), (235, 238, 240))
    img, _, _ = st.render_cube(_rng(9), R, t, extra=sheet)
    res = detect.detect(img, detect.DetectConfig(target='auto'))
    assert res.kinds == ('cube', 'sheet')
    assert [d.object_id for d in res.detections] == [0, 1]
    assert detect.detection_to_dict(res.detections[1])['target_type'] == 'sheet'


def test_auto_mode_names_each_sheet_after_the_size_it_fits():
    """One search for letter and A4: a real A4 page and tilted rendered sheets of both sizes."""
    cfg = detect.DetectConfig(target='auto')
    for _, img, true_px in list(_smartdoc())[:2]:
        dets = detect.detect(img, cfg).detections
        assert [d.name for d in dets] == ['a4']
        assert np.median(_sheet_errors(dets[0], true_px)[1]) <= 0.005
    for name, size_m in (('letter', (0.2159, 0.2794)), ('a4', (0.210, 0.297))):
        true_px = st.project_sheet((0.5, -0.3, 0.3), (0.05, 0.0, 0.9), size_m)
        img = st.render_sheet(_rng(13), true_px)
        dets = detect.detect(img, cfg, st.K).detections
        assert [d.name for d in dets] == [name]
        err = dets[0].vertices_px - true_px[detect_sheet._order(true_px)]
        assert np.hypot(*err.T).max() < 1.0


def test_bad_config_raises():
    with pytest.raises(ValueError):
        detect.DetectConfig(target='banana')
    with pytest.raises(ValueError):
        detect_cube.CubeConfig(roundness_min=0.9, roundness_max=0.5)
    for bad in ({'line_work_max_side_px': 0}, {'content_work_max_side_px': 0},
                {'content_close_px': -1},  # not a cv2.resize error in the first frame
                {'aspect_history': 1, 'aspect_history_min': 2}):  # would never refute
        with pytest.raises(ValueError):
            detect_sheet.SheetConfig(**bad)
    detect_sheet.SheetConfig(aspect_history=0, aspect_history_min=2)  # off: min unused
