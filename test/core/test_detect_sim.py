"""Detector tests on simulator frames (``absscale simulate``): distractors, hidden vertices,
motion blur and targets below the paper's 0.5% area, against the renderer's ground truth."""
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from absscale_ros.core import detect, detect_sheet, sheet_candidates

DATA = Path(__file__).parents[1] / 'data' / 'sim_frames'
FRAMES = json.loads((DATA / 'frames.json').read_text())['frames']


def _edge_lengths(fr):
    """Per visible vertex: the longest image edge at it (the paper's l), px."""
    v = fr['vertices_px']
    out = {}
    for i, vis in enumerate(fr['vertex_visible']):
        if vis:
            lens = [np.hypot(*np.subtract(v[b if a == i else a], v[i])) for a, b in fr['edges']
                    if i in (a, b) and v[b if a == i else a] is not None]
            out[i] = max(lens)
    return out


@pytest.mark.parametrize('fr', [f for f in FRAMES if f['covers_min_area']
                                and not f.get('hidden_corner')
                                and not f.get('blurred_hidden_corner')], ids=lambda f: f['file'])
def test_sim_frame_target_found_to_half_a_percent(fr):
    img = cv2.imread(str(DATA / fr['file']))
    res = detect.detect(img, detect.DetectConfig(target=fr['target']), np.array(fr['K']))
    kind = 'cube' if fr['target'] == 'cube' else 'sheet'
    assert [d.target_type for d in res.detections] == [kind]
    found = res.detections[0].vertices_px
    lengths = _edge_lengths(fr)
    true = np.array([fr['vertices_px'][i] for i in lengths])
    rel = np.array([np.hypot(*(found - t).T).min() / lengths[i]
                    for t, i in zip(true, lengths)])
    # Every visible vertex is found (within 10% of its edge: a match, not a neighbour) ...
    assert rel.max() < 0.1, fr['what']
    # ... to the requirement's 0.5% of the edge length (median; 1% under a long motion-blur
    # streak), and nothing extra is reported: each detected vertex is near a true one.
    assert np.median(rel) <= (0.005 if fr['motion_blur_px'] < 30.0 else 0.01), fr['what']
    extra = [np.hypot(*(true - p).T).min() for p in found]
    assert max(extra) < 0.1 * min(lengths.values()), fr['what']


@pytest.mark.parametrize('fr', [f for f in FRAMES if f.get('hidden_corner')],
                         ids=lambda f: f['file'])
def test_sim_frame_sheet_with_a_corner_under_a_box(fr):
    """
    A box standing on a sheet's corner (seeds 104 and 57 with ``occluded=true``): the three
    seen corners to the requirement's 0.5 % of their edge, the hidden one where its two
    sides' seen parts meet (within 1 %), scored lower than the seen ones. The base detector
    found neither: the small sheet's rough outline spent its five vertices on blunted
    corners, and on 57 the box cuts the sheet into two regions. On 57/216 the part beyond the
    box is a sliver the masks' opening removes, and the side under the box, refined along
    all of it, followed the box's foot (the session-14 detector found neither). On 85/210 the
    box stands over the near corner and the middle: the larger part seen is notched (solidity
    0.70, which kept it from the split path; the session-15 detector found no sheet).
    """
    img = cv2.imread(str(DATA / fr['file']))
    res = detect.detect(img, detect.DetectConfig(target=fr['target']), np.array(fr['K']))
    assert [d.target_type for d in res.detections] == ['sheet']
    d = res.detections[0]
    true = np.array(fr['vertices_px'])
    side = min(np.hypot(*(true[a] - true[b])) for a, b in fr['edges'])
    near = [int(np.argmin(np.hypot(*(d.vertices_px - t).T))) for t in true]
    assert sorted(near) == [0, 1, 2, 3]  # one detected vertex per true corner
    rel = np.array([np.hypot(*(d.vertices_px[j] - t)) / side for j, t in zip(near, true)])
    seen = np.array(fr['vertex_visible'])
    assert seen.sum() == 3 and rel[seen].max() <= 0.005 and rel[~seen].max() <= 0.01
    hidden = near[int(np.flatnonzero(~seen)[0])]
    assert d.scores()[hidden] < 0.5 < np.delete(d.scores(), hidden).min()


@pytest.mark.parametrize('fr', [f for f in FRAMES if f.get('sheet_px')], ids=lambda f: f['file'])
def test_sim_frame_outline_of_a_sheet_under_a_box_leaves_the_box_out(fr):
    """
    Seed 61 with ``occluded=true``: the box's corner reaches deep into the hull of the part
    of the sheet seen (a region of solidity 0.62-0.69, which the hidden-corner paths did not
    take before). The sheet's pixels are outlined along the box's notch, not across it as a
    chord (then the outline's precision against the true sheet pixels was 0.72 on both).
    Seed 82 frame 162: the stub path's outline was a chord from one side across the box to
    the far corner (precision 0.84, recall 0.87 in ``bench detect``'s count); the quad cut along
    the region seen gives 0.997 / 0.946. Seed 85 frame 210: the part seen is cut in two by
    the box, each part outlined along its own region.
    """
    img = cv2.imread(str(DATA / fr['file']))
    res = detect.detect(img, detect.DetectConfig(target=fr['target']), np.array(fr['K']))
    assert [d.target_type for d in res.detections] == ['sheet']
    truth, found = np.zeros(img.shape[:2], np.uint8), np.zeros(img.shape[:2], np.uint8)
    for polys, value in ((fr['sheet_px'], 1), (fr['sheet_holes_px'], 0)):
        for p in polys:
            cv2.fillPoly(truth, [np.round(np.array(p)).astype(np.int32)], value)
    for _, p in res.detections[0].polygons:
        cv2.fillPoly(found, [np.round(p).astype(np.int32)], 1)
    both = int(np.count_nonzero(truth & found))
    assert both >= 0.95 * np.count_nonzero(found)  # precision (0.98-0.99)
    assert both >= 0.95 * np.count_nonzero(truth)  # recall (0.97-0.98)


@pytest.mark.parametrize('fr', [f for f in FRAMES if f.get('blurred_hidden_corner')],
                         ids=lambda f: f['file'])
def test_sim_frame_blurred_sheet_under_a_box(fr):
    """
    A box on a sheet's far corner under a 27 px motion-blur streak (seed 80): the hidden-corner
    hypotheses are retried as blurred like whole sheets; the seen corners within 1.5 % of the
    shortest side (0.8-1.2 %: the streak), the hidden one within 2 % (0.8 %) and scored lower.
    """
    img = cv2.imread(str(DATA / fr['file']))
    res = detect.detect(img, detect.DetectConfig(target=fr['target']), np.array(fr['K']),
                        np.array(fr['D']))
    assert fr['motion_blur_px'] > 20.0
    assert [d.target_type for d in res.detections] == ['sheet']
    d = res.detections[0]
    true = np.array(fr['vertices_px'])
    side = min(np.hypot(*(true[a] - true[b])) for a, b in fr['edges'])
    near = [int(np.argmin(np.hypot(*(d.vertices_px - t).T))) for t in true]
    assert sorted(near) == [0, 1, 2, 3]
    rel = np.array([np.hypot(*(d.vertices_px[j] - t)) / side for j, t in zip(near, true)])
    seen = np.array(fr['vertex_visible'])
    assert seen.sum() == 3 and rel[seen].max() <= 0.015 and rel[~seen].max() <= 0.02
    hidden = near[int(np.flatnonzero(~seen)[0])]
    assert d.scores()[hidden] < 0.5 < np.delete(d.scores(), hidden).min()


def test_sim_frame_notched_region_off_finds_no_sheet_under_the_box():
    # ``sheet.notch_solidity`` 0.75 (the other hidden-corner paths' own bound) turns it off.
    fr = next(f for f in FRAMES if f['file'] == 'indoor_paper_61o_220.jpg')
    img = cv2.imread(str(DATA / fr['file']))
    cfg = detect.DetectConfig(target=fr['target'],
                              sheet=detect.detect_sheet.SheetConfig(notch_solidity=0.75))
    assert detect.detect(img, cfg, np.array(fr['K'])).detections == ()


@pytest.mark.parametrize('fr', [f for f in FRAMES if not f['covers_min_area']],
                         ids=lambda f: f['file'])
def test_sim_frame_small_target_rejected(fr):
    assert 0.0 < fr['area_fraction'] < 0.005
    img = cv2.imread(str(DATA / fr['file']))
    res = detect.detect(img, detect.DetectConfig(target=fr['target']), np.array(fr['K']))
    assert res.detections == (), fr['what']


def test_sim_frame_notched_regions_pass_the_area_and_roundness_tests():
    # ``region_shape`` gives 0 for a region too small, too round or too long: not a notched
    # one even at ``notch_solidity`` 0 (every solidity), which took them all in (specks too).
    img = cv2.imread(str(DATA / 'indoor_paper_61o_220.jpg'))
    cfg = detect_sheet.SheetConfig(sheet='a4', notch_solidity=0.0)
    scale = cfg.work_max_side_px / max(img.shape[:2])
    cands = sheet_candidates.Candidates(sheet_candidates.shrink(img, scale), cfg)
    h, w = cands.work_bgr.shape[:2]
    min_area = sheet_candidates.ROUGH_AREA_SLACK * cfg.min_area_frac * h * w
    shapes = [sheet_candidates.region_shape(c, min_area, cfg) for c, _ in cands.notched_regions]
    assert shapes and min(shapes) > 0.0
