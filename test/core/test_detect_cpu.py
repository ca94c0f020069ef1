"""The sheet detector's CPU savings keep its answers, on rendered frames."""
from dataclasses import replace
import json
from pathlib import Path
import sys

import cv2
import numpy as np

from absscale_ros.core import detect, detect_sheet, lines, sheet_candidates, sheet_checks, \
    sheet_partial, sheet_split, sheet_track, sides

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


def _shown_per_side(image_bgr, corners, lines_, colour=None):
    """``sheet_split.shown`` as it was written before vectorising: one side at a time."""
    h, w = image_bgr.shape[:2]
    ts = np.linspace(*sheet_split.SPAN, sheet_split.SAMPLES)
    ends = np.roll(corners, -1, axis=0)
    pts = corners[:, None] + ts[None, :, None] * (ends - corners)[:, None] \
        - sheet_split.INSIDE_PX * lines_[:, None, :2]
    u = np.clip(np.round(pts[..., 0]).astype(int), 0, w - 1)
    v = np.clip(np.round(pts[..., 1]).astype(int), 0, h - 1)
    bgr = image_bgr[v, u].astype(np.float64)
    colour = np.median(bgr.reshape(-1, 3), axis=0) if colour is None else colour
    ok = np.linalg.norm(bgr - colour, axis=2) < sheet_split.GO_ON_CONTRAST
    runs = np.zeros((4, 2, 2))
    for s in range(4):
        edges = np.flatnonzero(np.diff(np.concatenate([[0], ok[s].astype(int), [0]])))
        if len(edges):
            a, b = corners[s], ends[s]
            runs[s] = [a + ts[edges[1] - 1] * (b - a), a + ts[edges[-2]] * (b - a)]
    return ok.mean(axis=1), runs


def test_split_path_narrows_after_the_rough_tests_with_the_same_answer():
    """
    A page a box cuts in two (rendered seed 57, frames 216 and 252): the split path's
    hypotheses are narrowed (``sheet_split.narrowed``) only once they pass the rough corner
    tests, which is the same as narrowing all first, since narrowing never moves a corner;
    ``shown`` (vectorised) gives what the per-side walk gave, bit for bit.
    """
    data = Path(__file__).parents[1] / 'data' / 'sim_frames'
    frames = {f['file']: f for f in json.loads((data / 'frames.json').read_text())['frames']}
    for name in ('indoor_paper_57o_216.jpg', 'indoor_paper_57o_252.jpg'):
        img, K = cv2.imread(str(data / name)), np.array(frames[name]['K'])
        cfg = detect_sheet.SheetConfig(sheet='a4')
        scale = cfg.work_max_side_px / 1280.0
        cands = sheet_candidates.Candidates(sheet_candidates.shrink(img, scale), cfg)
        hyps = [h for r, _ in cands.split_regions
                for p in (sheet_partial.pentagon(r),) if p is not None
                for h in sheet_partial.hypotheses(lines.full_px(p, scale), 0.2)]
        band = max(6.0, 3.0 / scale)
        kept = [h for h in hyps if detect_sheet._rough_ok(h, False, True, img.shape, band,
                                                          cfg, K, None)]
        assert 0 < len(kept) < len(hyps)  # the tests drop some, and keep the page's
        narrowed = 0
        for h in hyps:
            out = sheet_split.narrowed(h, img)
            np.testing.assert_array_equal(out.corners, h.corners)
            narrowed += not np.array_equal(out.seen_ends, h.seen_ends)
            rough, _ = sheet_partial.rough_sides(h)
            for colour in (None, np.array([200.0, 205.5, 210.25])):
                want, got = _shown_per_side(img, h.corners, rough, colour), \
                    sheet_split.shown(img, h.corners, rough, colour)
                assert want[0].tobytes() == got[0].tobytes()
                assert want[1].tobytes() == got[1].tobytes()
        assert narrowed > 0
        assert len(detect_sheet.detect_sheets(img, cfg, K)) == 1


def test_split_path_tests_its_hypotheses_together_with_the_same_answer():
    """
    The split path's rough tests (``_rough_oks``: aspect errors of all hypotheses at once)
    and narrowing (``narrowed_many``: ``shown`` of all at once) give, bit for bit, what one
    hypothesis at a time gives, on the page a box cuts in two (seed 57, frame 216) and with
    lens distortion.
    """
    data = Path(__file__).parents[1] / 'data' / 'sim_frames'
    frames = {f['file']: f for f in json.loads((data / 'frames.json').read_text())['frames']}
    name = 'indoor_paper_57o_216.jpg'
    img, K = cv2.imread(str(data / name)), np.array(frames[name]['K'])
    cfg = detect_sheet.SheetConfig(sheet='a4', other_sheets=('letter',))
    scale = cfg.work_max_side_px / 1280.0
    cands = sheet_candidates.Candidates(sheet_candidates.shrink(img, scale), cfg)
    hyps = [h for r, _ in cands.split_regions + cands.white_regions
            for p in (sheet_partial.pentagon(r),) if p is not None
            for h in sheet_partial.hypotheses(lines.full_px(p, scale), 0.2)]
    band = max(6.0, 3.0 / scale)
    for dist in (None, np.array([-0.12, 0.03, 0.0, 0.0, 0.0])):
        one = [detect_sheet._rough_ok(h, False, True, img.shape, band, cfg, K, dist)
               for h in hyps]
        assert 0 < sum(one) < len(one)
        assert detect_sheet._rough_oks(hyps, False, True, img.shape, band, cfg, K,
                                       dist) == one
        errs = sheet_checks.aspect_errors(np.array([h.corners for h in hyps]), cfg, K, dist)
        assert errs.tobytes() == np.array([sheet_checks.aspect_error(
            h.corners, img.shape, cfg, K, dist) for h in hyps]).tobytes()
    many = sheet_split.narrowed_many(hyps, img)
    assert sum(not np.array_equal(m.seen_ends, h.seen_ends) for m, h in zip(many, hyps)) > 0
    for m, h in zip(many, hyps):
        assert m.seen_ends.tobytes() == sheet_split.narrowed(h, img).seen_ends.tobytes()


def _profiles_padded(image_bgr, lines_, ends, band_px, ns):
    """``sides._profiles`` as it was before sampling each side's own profiles only: every
    side sampled at the largest count, its repeats too."""
    q = sides._project_ends(lines_, ends)
    j = np.minimum(np.arange(ns.max())[None, :], ns[:, None] - 1)
    ts = sides.MARGIN + (1.0 - 2.0 * sides.MARGIN) * (j + 0.5) / ns[:, None]
    centres = q[:, None, 0, :] + ts[:, :, None] * (q[:, 1, :] - q[:, 0, :])[:, None, :]
    offs = np.arange(-band_px, band_px + 1e-9, sides.STEP_PX)
    s, n, k = len(lines_), centres.shape[1], len(offs)
    u, v = (centres[:, :, i, None] + offs * lines_[:, None, None, i] for i in (0, 1))
    samples = cv2.remap(image_bgr, u.reshape(s * n, k).astype(np.float32),
                        v.reshape(s * n, k).astype(np.float32), cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REPLICATE)
    return centres, offs, samples.reshape(s, n, k, 3).astype(np.float32)


def test_side_profiles_of_candidates_with_different_counts_are_the_padded_ones():
    """Sides of 16-64 profiles refined in one call: sampling each side's own profiles and
    copying its last one gives the samples (and refined lines) of sampling every side at the
    largest count, bit for bit, on a rendered frame."""
    _, img = _occluded([[680, 500], [800, 470], [830, 640], [700, 660]])
    rng = np.random.default_rng(7)
    p0 = rng.uniform(0, 1280, (40, 2)) * [1.0, 0.5625]
    p1 = p0 + rng.uniform(-300, 300, (40, 2))
    ls = np.array([lines.line_through(a, b, a + rng.normal(0, 50, 2)) for a, b in zip(p0, p1)])
    ends = np.stack([p0, p1], axis=1)
    for ns in (rng.integers(16, 65, 40), np.full(40, 33)):
        want = _profiles_padded(img, ls, ends, 8.0, ns)
        got = sides._profiles(img, ls, ends, 8.0, ns)
        assert all(a.tobytes() == b.tobytes() for a, b in zip(want, got))


def test_regions_among_many_small_white_ones_are_not_joined():
    """
    ``split_max_parts``: on an outdoor frame of light pavers (seed 4, frames 22 and 28) a
    paver region has a dozen small ones alike near it, and its joins (each a split-path
    hypothesis refined or more) go; a page a box cuts in two (seeds 57 and 85) has one or two
    parts near it, keeps every join and is still found.
    """
    data = Path(__file__).parents[1] / 'data' / 'sim_frames'
    frames = {f['file']: f for f in json.loads((data / 'frames.json').read_text())['frames']}
    cfg = detect_sheet.SheetConfig(sheet='letter', other_sheets=('a4',))
    for name, pages in (('outdoor_cube_4d_22.jpg', 0), ('outdoor_cube_4d_28.jpg', 0),
                        ('indoor_paper_57o_216.jpg', 1), ('indoor_paper_85o_210.jpg', 1)):
        img = cv2.imread(str(data / name))
        work = sheet_candidates.shrink(img, cfg.work_max_side_px / 1280.0)
        joins = [len(sheet_candidates.Candidates(work, replace(cfg, split_max_parts=m))
                     .split_regions) for m in (10 ** 6, cfg.split_max_parts)]
        assert joins[1] < 0.5 * joins[0] if pages == 0 else joins[1] == joins[0] > 0
        dets = detect_sheet.detect_sheets(img, cfg, np.array(frames[name]['K']))
        assert len(dets) == pages


def test_hidden_path_of_the_last_frame_tried_first_with_the_same_answer():
    """
    A video's last hidden-corner path (``SheetHistory.hidden_path``) is refined first, the
    others only when it finds nothing: on the rendered pages under a box (found by the stub,
    sharpened five-sided and split paths) every prior, the path that found the sheet, one
    before it or one after it, gives the sheet without a prior (to float rounding: the
    hypotheses are refined in other batches) and names the same path.
    """
    data = Path(__file__).parents[1] / 'data' / 'sim_frames'
    frames = [f for f in json.loads((data / 'frames.json').read_text())['frames']
              if f.get('hidden_corner')]
    paths = set()
    for fr in frames:
        img, K = cv2.imread(str(data / fr['file'])), np.array(fr['K'])
        cfg = detect.DetectConfig(target=fr['target'])
        runs = []
        for prior in (None,) + detect_sheet.HIDDEN_PATHS:
            history = sheet_track.SheetHistory()
            history.hidden_path = prior
            res = detect.detect(img, cfg, K, sheet_history=history)
            runs.append((res.detections, history.hidden_path))
        (want, path), others = runs[0], runs[1:]
        assert len(want) == 1 and path in detect_sheet.HIDDEN_PATHS, fr['file']
        paths.add(path)
        for got, got_path in others:
            assert got_path == path and len(got) == 1
            np.testing.assert_allclose(got[0].vertices_px, want[0].vertices_px, atol=1e-4)
            np.testing.assert_allclose(got[0].scores(), want[0].scores(), atol=1e-6)
    assert {'stub', 'sharp', 'split'} <= paths


def test_hidden_paths_after_the_last_frames_are_not_refined_when_it_finds_the_sheet(
        monkeypatch):
    """The point of ``hidden_path``: with the path that found the sheet as the prior, the
    later paths' hypotheses are not built nor refined (one batch of the paths up to it)."""
    data = Path(__file__).parents[1] / 'data' / 'sim_frames'
    frames = [f for f in json.loads((data / 'frames.json').read_text())['frames']
              if f.get('hidden_corner')]
    batches: list[int] = []
    refine = detect_sheet._accept_partial

    def counted(image_bgr, paths, *args, **kwargs):
        batches.append(len(paths))
        return refine(image_bgr, paths, *args, **kwargs)
    monkeypatch.setattr(detect_sheet, '_accept_partial', counted)
    checked = 0
    for fr in frames:
        img, K = cv2.imread(str(data / fr['file'])), np.array(fr['K'])
        cfg = detect.DetectConfig(target=fr['target'])
        first = sheet_track.SheetHistory()
        batches.clear()
        detect.detect(img, cfg, K, sheet_history=first)
        everything = batches[:1]
        path = first.hidden_path
        if path is None or path == detect_sheet.HIDDEN_PATHS[-1]:
            continue
        again = sheet_track.SheetHistory()
        again.hidden_path = path
        batches.clear()
        detect.detect(img, cfg, K, sheet_history=again)
        assert batches[:1] == [detect_sheet.HIDDEN_PATHS.index(path) + 1] < everything
        checked += 1
    assert checked >= 3
