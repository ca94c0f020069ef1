"""The sheet detector's CPU savings keep its answers, on rendered frames."""
from dataclasses import replace
from pathlib import Path
import sys

import numpy as np

from absscale_ros.core import detect_sheet, lines, sheet_candidates

sys.path.insert(0, str(Path(__file__).parent))
import synth_targets as st  # noqa: E402


def _occluded(box):
    true_px = st.sheet_corners(width_px=320, angle_deg=5)
    return true_px, st.render_sheet(np.random.default_rng(3), true_px,
                                    extra=lambda img: st.fill(img, box, (50, 60, 40)))


def test_scalar_rectangle_aspect_equals_the_batched_one():
    rng = np.random.default_rng(5)
    for _ in range(50):  # pages seen from many poses, with and without lens-free intrinsics
        tvec = (rng.uniform(-0.2, 0.2), rng.uniform(-0.1, 0.1), 0.9)
        quad = st.project_sheet(rng.uniform(-0.6, 0.6, 3), tvec)
        one = lines.rectangle_aspect(quad, st.K, 0.0, np.array([639.5, 359.5]))
        np.testing.assert_allclose(one, lines.rectangle_aspects(quad[None], st.K)[0],
                                   rtol=1e-12)
        assert abs(one / (297.0 / 210.0) - 1.0) < 1e-6  # and right: exact corners, A4


def test_hidden_paths_refined_together_keep_their_order():
    """
    Both hidden-corner paths' hypotheses go through one refinement, but the stub is only
    used when the five-sided regions give no sheet: the same answer as either path alone.
    """
    box = [[680, 500], [800, 470], [830, 640], [700, 660]]  # over the bottom right corner
    _, img = _occluded(box)
    both = detect_sheet.detect_sheets(img, detect_sheet.SheetConfig(sheet='a4'))
    pent = detect_sheet.detect_sheets(img, detect_sheet.SheetConfig(sheet='a4', stub_px=0.0))
    assert len(both) == len(pent) == 1
    np.testing.assert_array_equal(both[0].vertices_px, pent[0].vertices_px)
    np.testing.assert_array_equal(both[0].scores(), pent[0].scores())


def test_hidden_paths_see_whiteness_regions_only():
    """
    The colour-edge masks add regions (the desk between the page and the box, the box), but
    only the whiteness masks' regions feed the hidden-corner paths; the page is still found.
    """
    box = [[700, 100], [900, 100], [900, 300], [700, 300]]  # over the top right corner
    true_px, img = _occluded(box)
    cfg = detect_sheet.SheetConfig(sheet='a4')
    work = sheet_candidates.shrink(img, cfg.work_max_side_px / 1280.0)
    for line_mode in (False, True):  # (the colour-edge regions are kept for the line mode)
        cands = sheet_candidates.Candidates(work, replace(cfg, line_candidates=line_mode))
        white = [c for c, _ in cands.regions]
        cands.edge_quads()
        assert len(cands.regions) > len(white) if line_mode else len(cands.regions) == len(white)
        assert [c.tobytes() for c, _ in cands.white_regions] == [c.tobytes() for c in white]
    dets = detect_sheet.detect_sheets(img, cfg)
    assert len(dets) == 1
    far = np.hypot(*(dets[0].vertices_px[:, None] - true_px[None]).T).min(axis=0)
    assert np.median(far) < 1.0
