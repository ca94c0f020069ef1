"""
Sheet-of-paper detection: a bright, unsaturated quadrilateral on a darker surface.

The paper's indoor variant of Step 1. Candidates come from whiteness masks (the smallest of the
B, G, R channels is high only on white, unsaturated surfaces) at a few thresholds on a
downscaled image, filtered like the cube faces (area >= 0.005 of the image, roundness eq. 1
in [0.1, 0.85], area close to the convex hull), and simplified to four corners. Each side is
then refined on the full-resolution image: edge points where the whiteness drops across the
side (sub-pixel, on intensity profiles), a robust line fit, corners as intersections of the
refined lines. A candidate is kept when every side is backed by image gradient and the
rectangle it implies has the configured aspect ratio. When no whole sheet is found, five-sided
regions are tried as a sheet with one corner hidden (``sheet_partial``, ``min_seen``), also
when an object on the corner cuts the sheet in two (``sheet_split``) or the corner lies beyond
the image border (``sheet_border``).
"""
from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core import (lines, quads, sheet_border, sheet_candidates, sheet_checks,
                               sheet_partial, sheet_split, sheet_stub, sheet_track, sides,
                               targets)

Array = npt.NDArray[np.float64]
FIRST_PASS_SUPPORT = 0.25  # a side less supported after the widest refinement pass: no sheet
# Refinement bands after the widest, px: for a whole quad one fine pass is as exact as two on
# the tuning bags (sides seen in part need both: ``sheet_partial.FINE_BANDS``).
FINE_BANDS = (3.0,)
ROUGH_ASPECT_CAP = 2.0  # the largest rough aspect tolerance (long/short side ratio 1 to 3.9)
BLUR_MAX_QUADS = 2  # rough quadrilaterals retried as a blurred sheet, per frame
BLUR_MIN_RAMP_PX = 4.0  # a blurred sheet's most smeared side ramps over more (25-75 %)
BLUR_RAMP_PX = 8.0  # a ramp this wide (25-75 %) doubles the corner noise the aspect allows
BLUR_ASPECT_CAP = 2.0  # times ``aspect_tol``: the largest aspect tolerance of a blurred sheet
LINE_SEGMENTS = 40  # segment lines added to the Hough peaks of the line hypotheses (``quads``)
SMALL_INSET_PX = 2.0  # work px a region may reach beyond a refined too-small sheet (rough outline)
# of ``min_seen``: a part the occluder cut off is a small region, whose rough outline falls
# short of the side it shows by a work pixel or two (the refined sides are exact)
SPLIT_SEEN = 0.5
STUB_MAX_HYPS = 8  # stub hypotheses refined per frame at most (whitest, longest sides first)
NOTCH_MAX_HYPS = 4  # ... and of the notched regions (``Candidates.notched_regions``)
NOTCH_INSIDE = 0.95  # of a region's outline within a hidden-corner sheet's: the part seen
NOTCH_SLACK_PX = 2.0  # work px a region's outline may lie outside that sheet's outline
SEEN_PARTS = 2  # parts of a sheet seen in parts (the split path's: a region and a part)
CLIP_AREA_TOL = 0.25  # a clipped seen outline's area may differ from its region's by this
# The hidden-corner paths of ``_accept_hidden``, in the order they are tried.
HIDDEN_PATHS = ('five', 'stub', 'sharp', 'split', 'border')


@dataclass(frozen=True)
class SheetConfig:
    """
    Thresholds of the sheet detector; defaults are the paper's values where it gives one.

    :param sheet: 'letter', 'a4' or 'custom' (then ``size_m`` is used).
    :param size_m: (short, long) side of a custom sheet, m.
    :param other_sheets: further sheet names accepted in the same search ('auto' mode): one
        candidate search for all sizes, each detection named after the size whose aspect it
        fits best.
    :param min_area_frac: smallest sheet area over image area (paper: 0.005).
    :param roundness_min: lower roundness bound, eq. 1 (paper: 0.1).
    :param roundness_max: upper roundness bound, eq. 1 (paper: 0.85).
    :param min_solidity: smallest region area over its convex hull area (convexity test).
    :param aspect_tol: largest relative deviation of the recovered long/short side ratio
        (without intrinsics: the deviation allowed).
    :param aspect_floor: with intrinsics, the smallest deviation allowed (lens distortion, a
        sheet cut a little off size); more where the corners fix the ratio less well.
    :param aspect_corner_px: with intrinsics, the deviation allowed is the one corner shifts of
        this many px cause (``sheet_checks.aspect_tolerance``; 0 allows ``aspect_tol``).
    :param min_support: smallest fraction of each side backed by an image edge.
    :param min_contrast: smallest BGR colour step across every side (0-255).
    :param work_max_side_px: the candidate search runs on an image at most this big.
    :param canny_low: lower Canny threshold of the colour-edge candidates (BGR, 0-255).
    :param canny_high: upper Canny threshold of the colour-edge candidates.
    :param focal_frac: focal length over the larger image side, used to predict a sheet's
        hidden side when no camera model is given (``sheet_stub``).
    :param focal_range: (smallest, largest) focal length over the larger image side that the
        aspect check allows when no camera model is given (phones, webcams: 0.6-1.2).
    :param line_candidates: when the masks give no sheet, also try quadrilaterals of straight
        edges scored by gradient support (``quads``): a page on other pages or on a desk of
        the same white. Off for video: in a textured room it costs tens of ms on every frame
        without a sheet; ``absscale detect`` (still images) turns it on.
    :param line_work_max_side_px: the line search runs on an image at most this big.
    :param line_max_refine: line hypotheses refined at full resolution, best supported first.
    :param content_close_px: when the line search finds no sheet, it is run again on the image
        with its dark thin strokes closed away (a grey-level closing with a disc this many px
        wide at ``content_work_max_side_px``): a page's text and table lines outvote its
        sides, and a desk's grain its surroundings, on the image as it is (0 turns it off).
    :param content_work_max_side_px: the closing runs on an image at most this big.
    :param max_inside_spread: largest distance of the colour just inside one side from the
        median over the four sides, over the brightest channel of that median (one sheet).
    :param max_saturation: largest (max - min) / max channel of that median colour (paper is
        unsaturated; a shaded sheet or a warm light stays well below this).
    :param max_outside_spread: the same spread test just outside the sides (the surface the
        sheet lies on), looser: shadows and a second surface at one side are common.
    :param max_shade: the inside (and outside) colours of the four sides may differ in
        brightness up to this factor when their hues agree: a shadow across the sheet and
        its surface (``sheet_checks.one_colour``; 1.0 turns it off).
    :param min_inside_ratio: smallest brightness (brightest channel) just inside every side
        over just outside it: paper is not darker than the surface it lies on (true sides of
        real and rendered pages: 0.92 or more). A side on the far edge of a dark band beyond the
        page passed the shade-tolerant colour test at 0.45.
    :param rough_aspect_tol: the aspect test on rough mask corners, before refinement (wide:
        a small sheet seen obliquely has rough corners a few px off on 40 px sides).
    :param max_ridges: most sides whose colour recovers beyond a thin dark line
        (``sides.ridge_ratio`` above ``ridge_ratio``): four are a floor tile between grout.
    :param ridge_ratio: ``sides.ridge_ratio`` above which a side is such a line.
    :param min_seen: a hidden corner is extrapolated only when both sides meeting there are
        seen over at least this fraction of their length (1.0 turns it off).
    :param stub_px: a sheet whose hidden corner covers nearly all of one side is recovered
        from the camera intrinsics when that side shows an edge over this many px next to
        its seen corner (``sheet_stub``; 0 turns it off).
    :param notch_solidity: regions of the whiteness masks down to this solidity (area over
        convex hull area; the other hidden-corner paths take 0.75 or more) are tried as a
        stub sheet (``sheet_stub``): a box standing on a sheet's corner whose own corner
        reaches deep into the part seen, hiding nearly all of one side (0.75 or more: off).
    :param split_gap: a region may be joined with a small white region at most this many
        times its size (square root of its area) away, for the hidden-corner path: a box on
        a sheet's corner, seen from low, cuts the sheet in two (``sheet_split``; 0 turns it
        off).
    :param split_max_parts: a region with more small white regions than this within
        ``split_gap`` is joined with none (``sheet_candidates.Candidates._add_split``): paving
        or tiles, not a sheet a box cuts in two.
    :param border_corner: a corner beyond the image border is extrapolated like a hidden one
        (``sheet_border``: both sides at it seen over ``min_seen``, the cut along the border),
        also under motion blur (``blur_band_frac``): a pan sweeps the sheet out of view.
    :param blur_band_frac: when no whole sheet is found, rough quadrilaterals are retried as
        a motion-blurred sheet (before the hidden-corner paths), each side searched this
        fraction of the shorter side either side (``_accept_blurred``; 0 turns it off).
    :param aspect_history: frames of a video (``detect_sheets``' ``history``) over which a whole
        rectangle's aspect errors are kept: one that passes the aspect test in this frame is
        not reported when the median of its error over the tolerance over the frames it was
        measured in, this one included, is above one (``sheet_track``: a 4:3 board passes in
        the odd frame where corner noise pulls it towards letter; 0 turns it off).
    :param aspect_history_min: ... when it was measured in at least this many of those
        frames before this one.
    """

    sheet: str = 'letter'
    size_m: tuple[float, float] = (0.0, 0.0)
    other_sheets: tuple[str, ...] = ()
    min_area_frac: float = 0.005
    roundness_min: float = 0.1
    roundness_max: float = 0.85
    min_solidity: float = 0.85
    aspect_tol: float = 0.08
    aspect_floor: float = 0.02
    aspect_corner_px: float = 1.5
    min_support: float = 0.5
    min_contrast: float = 10.0
    work_max_side_px: int = 480
    focal_frac: float = 0.9
    focal_range: tuple[float, float] = (0.6, 1.2)
    canny_low: int = 20
    canny_high: int = 50
    line_candidates: bool = False
    line_work_max_side_px: int = 320
    line_max_refine: int = 3
    content_close_px: int = 9
    content_work_max_side_px: int = 640
    max_inside_spread: float = 0.25
    max_saturation: float = 0.35
    max_outside_spread: float = 0.5
    max_shade: float = 2.5
    min_inside_ratio: float = 0.75
    rough_aspect_tol: float = 0.8
    max_ridges: int = 1
    ridge_ratio: float = 0.3
    min_seen: float = 0.4
    stub_px: float = 8.0
    notch_solidity: float = 0.55
    split_gap: float = 2.0
    split_max_parts: int = 4
    border_corner: bool = True
    blur_band_frac: float = 0.4
    aspect_history: int = 20
    aspect_history_min: int = 2

    def __post_init__(self) -> None:
        if not 0.0 < self.min_area_frac < 1.0:
            raise ValueError(f'min_area_frac must be in (0, 1), got {self.min_area_frac}')
        if not 0.0 <= self.roundness_min < self.roundness_max <= 1.0:
            raise ValueError('need 0 <= roundness_min < roundness_max <= 1')
        if min(self.work_max_side_px, self.line_work_max_side_px,
               self.content_work_max_side_px) < 64:  # (0 failed in cv2.resize, mid-run)
            raise ValueError('work_max_side_px, line_work_max_side_px and '
                             'content_work_max_side_px must be >= 64')
        if self.content_close_px < 0:
            raise ValueError(f'content_close_px must be >= 0, got {self.content_close_px}')
        if not 0.0 < self.focal_range[0] <= self.focal_range[1]:
            raise ValueError(f'focal_range must be 0 < low <= high, got {self.focal_range}')
        if not 0.0 < self.aspect_floor <= self.aspect_tol:
            raise ValueError(f'need 0 < aspect_floor <= aspect_tol, got {self.aspect_floor}')
        if self.split_max_parts < 1:
            raise ValueError(f'split_max_parts must be >= 1, got {self.split_max_parts}')
        if self.max_shade < 1.0:
            raise ValueError(f'max_shade must be >= 1, got {self.max_shade}')
        # (a window shorter than aspect_history_min frames could never refute: silently off)
        if self.aspect_history < 0 or self.aspect_history_min < 1 or \
                0 < self.aspect_history < self.aspect_history_min:
            raise ValueError('need aspect_history >= 0 and 1 <= aspect_history_min <= '
                             f'aspect_history (or 0), got {self.aspect_history}, '
                             f'{self.aspect_history_min}')
        self.models()  # raises ValueError on an unknown sheet

    def model(self) -> targets.SheetModel:
        """Return the configured sheet model."""
        size = self.size_m if self.sheet == 'custom' else None
        return targets.sheet_model(self.sheet, size)

    def models(self) -> list[targets.SheetModel]:
        """Return the configured sheet model, then those of ``other_sheets``."""
        return [self.model()] + [targets.sheet_model(n) for n in self.other_sheets
                                 if n != self.sheet]


def _order(corners: Array) -> npt.NDArray[np.intp]:
    """Return the order of corners clockwise on screen (y down) from the smallest u + v."""
    centre = corners.mean(axis=0)
    ang = np.arctan2(corners[:, 1] - centre[1], corners[:, 0] - centre[0])
    idx = np.argsort(ang)  # increasing angle is clockwise when y points down
    return np.roll(idx, -int(np.argmin(corners[idx].sum(axis=1))))


def refine_quad(image_bgr: npt.NDArray[np.uint8], quad_px: Array, coarse_band_px: float
                ) -> tuple[Array, Array, Array, Array, Array] | None:
    """
    Refine a rough quadrilateral's sides on the colour step across each and intersect them.

    The four sides are refined together (``sides.refine``), each on the image projected on
    its own inside-minus-outside colour, so a sheet that is brighter than the desk on one side
    and only differently tinted on another is handled alike.

    :returns: ((4, 2) corners px, (4,) side supports, (4,) colour steps, (4, 3) BGR colour
        just inside each side, (4, 3) just outside) or None when the sides do not close.
    """
    return _refine_quads(image_bgr, [quad_px], coarse_band_px)[0]


def _refine_quads(image_bgr: npt.NDArray[np.uint8], quads_px: list[Array], coarse_band_px: float,
                  bands: tuple[float, ...] | None = None, blurred: bool = False
                  ) -> list[sides.Refined | None]:
    """``refine_quad`` of several quadrilaterals, in one ``sides.refine`` call per pass
    (``bands``: instead of the coarse band and ``FINE_BANDS``; ``blurred``: see
    ``sides.refine``)."""
    ends = [np.stack([q, np.roll(q, -1, axis=0)], axis=1) for q in quads_px]
    rough = [np.array([lines.line_through(p0, p1, q.mean(axis=0)) for p0, p1 in e])
             for q, e in zip(quads_px, ends)]
    ns = [int(np.clip(np.linalg.norm(e[:, 1] - e[:, 0], axis=1).mean() / 4.0, 16, 64))
          for e in ends]
    outs = sides.refine_many(image_bgr, rough, ends, bands or (coarse_band_px,) + FINE_BANDS,
                             ns, FIRST_PASS_SUPPORT, blurred=blurred)
    return [None if o is None else _quad_from_sides(q, o, coarse_band_px)
            for q, o in zip(quads_px, outs)]


def _quad_from_sides(quad_px: Array, out: sides.Refined, coarse_band_px: float
                     ) -> sides.Refined | None:
    """Return ``refine_quad``'s result from the refined sides ``out``, or None."""
    refined, supports, steps, inside, outside = out
    corners = lines.quad_corners(list(refined))
    if corners is None or not cv2.isContourConvex(corners.astype(np.float32)):
        return None
    if np.abs(corners - quad_px).max() > 2.0 * coarse_band_px + 4.0:
        return None
    return corners, supports, steps, inside, outside


def detect_sheets(image_bgr: npt.NDArray[np.uint8], cfg: SheetConfig,
                  K: Array | None = None, half: npt.NDArray[np.uint8] | None = None,
                  dist: Array | None = None, history: sheet_track.SheetHistory | None = None
                  ) -> list[targets.TargetDetection]:
    """
    Find every sheet of the configured size in a BGR image.

    Candidates come from the region masks first; only when none passes are quadrilaterals of
    straight edges tried (``quads``), which costs a few more milliseconds.

    :param image_bgr: (H, W, 3) uint8 BGR image.
    :param K: (3, 3) intrinsics px for the aspect check, or None to estimate.
    :param half: the image box-filtered to half its size, when another detector made it.
    :param dist: OpenCV distortion coefficients of the camera (the aspect check undoes them).
    :param history: for frames of one video in order: the aspect errors of the rectangles
        seen in the last frames (``cfg.aspect_history``); None: this frame alone.
    :returns: detections, best first; each has 4 corners ordered as in ``targets``.
    """
    # (the aspect errors with cfg.aspect_history only; the hidden-corner path of any video)
    aspects = history if history is not None and cfg.aspect_history > 0 else None
    if aspects is not None:
        aspects.next_frame(cfg.aspect_history)
    h, w = image_bgr.shape[:2]
    scale = min(1.0, cfg.work_max_side_px / max(h, w))
    work = sheet_candidates.shrink(image_bgr, scale, half)
    found: list[Found] = []
    band = max(6.0, 3.0 / scale)
    cands = sheet_candidates.Candidates(work, cfg)
    small: list[Array] = []
    unfound = _accept_quads(image_bgr, [lines.full_px(q, scale) for q in cands.quads], band,
                            cfg, K, found, dist, small, aspects)
    if not found:  # the colour-edge masks only when the whiteness masks show no sheet
        unfound += _accept_quads(image_bgr, [lines.full_px(q, scale)
                                             for q in cands.edge_quads()], band, cfg, K, found,
                                 dist, small, aspects)
    if not found and cfg.line_candidates:
        more = sheet_candidates.colour_quads(work, cands.regions, cfg) + \
            sheet_candidates.detached_quads(work, cfg) + sheet_candidates.chroma_quads(work, cfg)
        _accept_quads(image_bgr, [lines.full_px(q, scale) for q in more], band, cfg, K, found,
                      dist, history=aspects)
    for closed in (False, True):
        if found or not cfg.line_candidates or (closed and cfg.content_close_px <= 0):
            break
        line_quads = _line_candidates(image_bgr, cfg, closed)
        if line_quads:  # (refined on the image as it is)
            _accept_quads(image_bgr, [q for q, _ in line_quads], line_quads[0][1], cfg, K, found,
                          dist, history=aspects)
    if not found and cfg.blur_band_frac > 0.0:
        _accept_blurred(image_bgr, unfound, band, cfg, K, found, dist, aspects)
    path = None
    if not found:
        hidden = [r for r in cands.white_regions if not _whole_small(r[0], small, scale)]
        path = _accept_hidden(image_bgr, hidden, scale, band, cfg, K, found, dist, cands,
                              [r for r in cands.notched_regions
                               if not _whole_small(r[0], small, scale)],
                              None if history is None else history.hidden_path)
    if history is not None:
        history.hidden_path = path
    found.sort(key=lambda f: -f[0])
    return [_detection(f, sheet_checks.best_model(f[1], image_bgr.shape, cfg, K)) for f in found]


def _line_candidates(image_bgr: npt.NDArray[np.uint8], cfg: SheetConfig, closed: bool = False
                     ) -> list[tuple[Array, float]]:
    """Return (full-resolution quad, refinement band px) hypotheses from straight edges
    (``closed``: of the image without its thin dark strokes, ``content_close_px``)."""
    h, w = image_bgr.shape[:2]
    scale = min(1.0, cfg.line_work_max_side_px / max(h, w))
    src = _without_strokes(image_bgr, cfg) if closed else image_bgr
    work = cv2.resize(src, (round(w * scale), round(h * scale)), interpolation=cv2.INTER_AREA)
    aspect = max(m.aspect for m in cfg.models())
    min_side = np.sqrt(cfg.min_area_frac * work.shape[0] * work.shape[1] / aspect)
    hyps, _ = quads.find_quads(work, quads.QuadConfig(min_side_px=float(min_side),
                                                      segment_lines=LINE_SEGMENTS))
    kept: list[Array] = []
    for quad in hyps:  # best supported first
        # Rough corners: a looser test here, the exact one after refinement.
        if not sheet_checks.aspect_ok(quad, work.shape, cfg, None, 2.0 * cfg.aspect_tol):
            continue
        if all(np.abs(quad - q).max() > 2.0 for q in kept):  # neighbouring Hough peaks
            kept.append(quad)
        if len(kept) == cfg.line_max_refine:
            break
    return [(lines.full_px(q, scale), max(6.0, 3.0 / scale)) for q in kept]


def _without_strokes(image_bgr: npt.NDArray[np.uint8], cfg: SheetConfig
                     ) -> npt.NDArray[np.uint8]:
    """
    Return the image shrunk to ``content_work_max_side_px`` with dark strokes thinner than
    ``content_close_px`` closed away: printed text and rules turn into the page's white, a
    cable across it into paper or desk, and the outline of anything wider stays where it is.
    """
    h, w = image_bgr.shape[:2]
    scale = min(1.0, cfg.content_work_max_side_px / max(h, w))
    small = cv2.resize(image_bgr, (round(w * scale), round(h * scale)),
                       interpolation=cv2.INTER_AREA)
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (cfg.content_close_px,) * 2)
    return cv2.morphologyEx(small, cv2.MORPH_CLOSE, disc)


# A sheet found: (score, (4, 2) corners, outline of the seen part (or a tuple of outlines of
# its parts), (4,) vertex scores or None).
Found = tuple[float, Array, Array | tuple[Array, ...], Array | None]
Refined = sides.Refined
# and the seen outline
Refined6 = tuple[Array, ...]


def _accept(image_bgr: npt.NDArray[np.uint8], quad_full: Array, band: float, cfg: SheetConfig,
            K: Array | None, found: list[Found]) -> None:
    """Refine a candidate; append it to ``found`` when it passes every test."""
    _accept_quads(image_bgr, [quad_full], band, cfg, K, found)


def _accept_quads(image_bgr: npt.NDArray[np.uint8], quads_full: list[Array], band: float,
                  cfg: SheetConfig, K: Array | None, found: list[Found],
                  dist: Array | None = None, small: list[Array] | None = None,
                  history: sheet_track.SheetHistory | None = None) -> list[Array]:
    """
    Refine candidates (all at once, ``_refine_quads``); append each that passes every test to
    ``found``, in order (and that ``history`` does not refute, ``_passes_history``). Return
    those whose sides were not found or not supported (for ``_accept_blurred``); append to
    ``small`` the refined corners of those whose four sides are all supported but which are
    too small (``_whole_small``).
    """
    # Rough corners: a looser aspect test here, the exact one after refinement.
    quads_full = [q for q in quads_full if _rough_aspect_ok(q, image_bgr.shape, band, cfg, K,
                                                            dist)]
    unfound = []
    for quad, refined in zip(quads_full, _refine_quads(image_bgr, quads_full, band)):
        if refined is None or refined[1].min() < cfg.min_support:
            unfound.append(quad)
        elif small is not None and not sheet_checks.big_enough(refined[0], image_bgr.shape, cfg):
            small.append(refined[0])
        if refined is None or any(
                np.hypot(*(quad[:, None] - f[1][None]).T).min(axis=0).max() <= band
                for f in found):
            continue  # or another mask's outline of a sheet already found
        # (``_passes`` applies the floor-tile test to the refined corners: refining every
        # candidate together costs less than testing the rough ones first)
        if sheet_checks.big_enough(refined[0], image_bgr.shape, cfg) and \
                _passes_history(image_bgr, refined, cfg, K, dist, history) and \
                all(np.abs(refined[0] - f[1]).max() > 4.0 for f in found):
            found.append((float(refined[1].mean()), refined[0], refined[0], None))
    return unfound


def _passes_history(image_bgr: npt.NDArray[np.uint8], refined: Refined, cfg: SheetConfig,
                    K: Array | None, dist: Array | None,
                    history: sheet_track.SheetHistory | None,
                    aspect_tol: float | None = None) -> bool:
    """``sheet_checks.passes`` of a whole quadrilateral, noting its aspect error in
    ``history`` (when given), which must not refute it (``sheet_track``)."""
    if history is None:
        return sheet_checks.passes(image_bgr, refined, cfg, K, aspect_tol=aspect_tol, dist=dist)
    ratio: list[float] = []
    ok = sheet_checks.passes(image_bgr, refined, cfg, K, aspect_tol=aspect_tol, dist=dist,
                             note=ratio.append)
    if ratio:
        history.note(refined[0], ratio[0])
    return ok and not history.refuted(refined[0], cfg.aspect_history, cfg.aspect_history_min)


def _whole_small(contour: npt.NDArray[np.int32], small: list[Array], scale: float) -> bool:
    """
    Return True when a work-image region lies within (``SMALL_INSET_PX``) one of the ``small``
    refined quadrilaterals (full px): a whole sheet too small to count, whose hidden-corner
    hypotheses could only outline the same too small seen part (``big_enough``), so they are
    not refined (far sheets: most frames of a walk-through).
    """
    pts = lines.full_px(contour.reshape(-1, 2), scale)
    for quad in small:
        if -lines.depths_inside(pts, lines.side_lines(quad)).min() <= SMALL_INSET_PX / scale:
            return True
    return False


def _rough_aspect_ok(quad: Array, shape: tuple[int, ...], band: float, cfg: SheetConfig,
                     K: Array | None, dist: Array | None, err: float | None = None) -> bool:
    """
    The aspect test of rough corners: within ``cfg.rough_aspect_tol``, or with intrinsics more
    where corners anywhere within the refinement ``band`` change the ratio more (a small
    sheet seen nearly edge-on: 35 px tall, 1.0 off at rough corners 7 px off, 0.2 % once
    refined). ``err``: their ``sheet_checks.aspect_error``, when known.
    """
    err = sheet_checks.aspect_error(quad, shape, cfg, K, dist) if err is None else err
    cap = ROUGH_ASPECT_CAP / cfg.aspect_tol
    # (an error over the largest tolerance ``aspect_tolerance`` can return, computed as it
    # does, fails without its nine aspects: 58 % of the calls on pages under a box)
    if err <= cfg.rough_aspect_tol or K is None or err > cap * cfg.aspect_tol:
        return err <= cfg.rough_aspect_tol
    noise = band / cfg.aspect_corner_px if cfg.aspect_corner_px > 0.0 else 1.0
    return err <= sheet_checks.aspect_tolerance(quad, cfg, K, noise, cap, dist)


def _side_ramps(image_bgr: npt.NDArray[np.uint8], quad: Array, wide: float,
                inside: Array | None, outside: Array | None) -> Array:
    """Ramp width of each side of ``quad`` in a band ``wide`` px either way (colours at the
    band's ends unless given), sampled at the blur retry's step."""
    ends = np.stack([quad, np.roll(quad, -1, axis=0)], axis=1)
    ls = np.array([lines.line_through(a, b, quad.mean(axis=0)) for a, b in ends])
    return sides.ramp_widths(image_bgr, ls, ends, wide, inside, outside,
                             step_px=sides.blur_step(wide))


def _accept_blurred(image_bgr: npt.NDArray[np.uint8], quads_full: list[Array], band: float,
                    cfg: SheetConfig, K: Array | None, found: list[Found],
                    dist: Array | None = None,
                    history: sheet_track.SheetHistory | None = None) -> None:
    """
    Retry the rough quadrilaterals as a sheet smeared by motion blur: its sides are ramps
    longer than the refinement band, whose steepest point wanders along them. Each side is
    found at the mid level between the colours inside and outside (``sides.refine`` with
    ``blurred``) in a band of ``cfg.blur_band_frac`` of the quadrilateral's shorter side.
    Only quadrilaterals whose sides the sharp refinement did not find come here (a sharp
    board of the wrong aspect is not retried), one side must ramp over ``BLUR_MIN_RAMP_PX``
    or more, like its opposite side, and the aspect test allows corner shifts growing with
    the ramp (``BLUR_RAMP_PX``), up to
    ``BLUR_ASPECT_CAP`` times ``cfg.aspect_tol``.
    """
    for quad in quads_full[:BLUR_MAX_QUADS]:
        wide = _blur_band(quad, band, cfg)
        if not _motion_ramps(_side_ramps(image_bgr, quad, wide, None, None)):
            continue  # already along the rough sides (the test below)
        refined = _refine_quads(image_bgr, [quad], wide, (wide, 0.5 * wide), blurred=True)[0]
        if refined is None or not sheet_checks.big_enough(refined[0], image_bgr.shape, cfg):
            continue
        ramps = _side_ramps(image_bgr, refined[0], wide, refined[3], refined[4])
        if not _motion_ramps(ramps):
            continue  # sharp, or one side smeared by something else than motion
        tol = _blur_aspect_tol(refined[0], ramps, cfg, K, dist)
        if _passes_history(image_bgr, refined, cfg, K, dist, history, tol):
            found.append((float(refined[1].mean()), refined[0], refined[0], None))
            return  # one blurred sheet at most: the masks outline it several times


def _blur_band(corners: Array, band: float, cfg: SheetConfig) -> float:
    """The band, px, a blurred sheet's sides are looked for in: ``cfg.blur_band_frac`` of
    its shorter side, at least the sharp ``band``."""
    side = float(np.linalg.norm(corners - np.roll(corners, -1, axis=0), axis=1).min())
    return max(band, cfg.blur_band_frac * side)


def _motion_ramps(ramps: Array) -> bool:
    """Return True when the sides' ramp widths, px, look like motion blur: one ramps over
    ``BLUR_MIN_RAMP_PX`` or more, and opposite sides alike (``_blur_alike``)."""
    return bool(ramps.max() >= BLUR_MIN_RAMP_PX) and _blur_alike(ramps)


def _blur_aspect_tol(corners: Array, ramps: Array, cfg: SheetConfig, K: Array | None,
                     dist: Array | None, slack: float = 1.0) -> float:
    """The aspect tolerance of a blurred sheet: corner shifts grow with the widest ramp
    (``BLUR_RAMP_PX``; ``slack`` times more), up to ``BLUR_ASPECT_CAP`` times
    ``cfg.aspect_tol``."""
    return sheet_checks.aspect_tolerance(corners, cfg, K,
                                         slack * max(1.0, float(ramps.max()) / BLUR_RAMP_PX),
                                         BLUR_ASPECT_CAP, dist)


def _blur_alike(ramps: Array) -> bool:
    """
    Return True when opposite sides (nearly parallel: a motion streak crosses them alike)
    ramp over similar widths, px: a lit or shaded band along one side of a board is not blur.
    """
    pairs = ramps.reshape(2, 2).T  # (0, 2) and (1, 3)
    gap = np.abs(pairs[:, 0] - pairs[:, 1])
    return bool((gap <= np.maximum(2.0, 0.5 * pairs.max(axis=1))).all())


def _accept_hidden(image_bgr: npt.NDArray[np.uint8], regions: list[sheet_candidates.Region],
                   scale: float, band: float, cfg: SheetConfig, K: Array | None,
                   found: list[Found], dist: Array | None,
                   cands: sheet_candidates.Candidates | None = None,
                   notched: list[sheet_candidates.Region] | None = None,
                   prior: str | None = None) -> str | None:
    """
    The hidden-corner paths (``HIDDEN_PATHS``, in order): five-sided regions
    (``sheet_partial``, when ``cfg.min_seen`` < 1), then, when they give no sheet, a stub
    (``sheet_stub``, ``cfg.stub_px`` > 0; also of the ``notched`` regions,
    ``Candidates.notched_regions``, up to ``NOTCH_MAX_HYPS`` more), the sharpened five-sided
    outlines, the ``cands.split_regions`` (a region joined with a part an occluder cut off)
    and the ``cands.border_regions`` (a corner beyond the border). Their hypotheses are
    refined in one ``_accept_partial`` call: a frame without a sheet tries all, and one call
    per pass costs about a millisecond less than one per path. With ``prior``, the path that
    found the last frame's sheet, the paths up to it are refined first and the others only
    when they find none (most frames of a page under a box: the later paths' hypotheses were
    most of their refinement). A sheet found gets the region seen as its outline
    (``_follow_notches``; the split path's cut-off parts: a sheet seen in parts); with none
    found, the corner-beyond-the-border and five-sided hypotheses are retried as smeared by
    motion blur (``_accept_blurred_border``). Return the name of the path that found a sheet,
    or None.
    """
    five: list[list[sheet_partial.Partial]] = []
    outside: list[list[sheet_partial.Partial]] = []
    parts: list[sheet_candidates.Region] = []

    def five_path() -> _Hidden:
        # (the five-sided regions' hypotheses, grouped by region: retried as blurred below)
        five.extend(sheet_partial.hypotheses(lines.full_px(p, scale), cfg.min_seen)
                    for p in sheet_candidates.pentagons(regions))
        return _Hidden(five, lambda hyp, out: sheet_partial.finish(hyp, out, band))

    def sharp_path() -> _Hidden:
        # The outlines the paths above did not try (only where they find nothing), the
        # hidden corner then covered by something that is neither the sheet nor its surface.
        pents = [lines.full_px(p, scale) for p in sheet_candidates.pentagons(regions, True)]
        return _Hidden([sheet_partial.hypotheses(p, cfg.min_seen) for p in pents],
                       lambda hyp, out: sheet_partial.finish(hyp, out, band),
                       strict_cover=True)

    def split_path() -> _Hidden:
        path = _split_path(image_bgr, cands.split_regions, scale, band, cfg, K, dist)
        parts.extend(cands.split_parts)
        return path

    def border_path() -> _Hidden:
        outside.extend(sheet_border.groups(cands.border_regions, cands.work_bgr, cfg, scale,
                                           image_bgr.shape))
        return _Hidden(outside, lambda hyp, out: sheet_partial.finish(hyp, out, band),
                       border=True)

    partial = cfg.min_seen < 1.0
    makers = {'five': five_path if partial else None,
              'stub': (lambda: _stub_path(image_bgr, regions, notched or [], scale, band, cfg,
                                          K)) if cfg.stub_px > 0.0 else None,
              'sharp': sharp_path if partial else None,
              'split': split_path if partial and cfg.split_gap > 0.0 and cands else None,
              'border': border_path if partial and cfg.border_corner and cands else None}
    names = [n for n in HIDDEN_PATHS if makers[n] is not None]
    cut = names.index(prior) + 1 if prior in names else len(names)
    path = None
    for batch in (names[:cut], names[cut:]):
        if found or not batch:
            continue
        at = _accept_partial(image_bgr, [makers[n]() for n in batch], band, cfg, K, found,
                             dist=dist)
        path = None if at is None else batch[at]
    _follow_notches(found, regions + (notched or []), scale, parts)
    if not found and cfg.blur_band_frac > 0.0:
        _accept_blurred_border(image_bgr, [h for g in outside for h in g], band, cfg, K, found,
                               dist)
    if not found and cfg.blur_band_frac > 0.0 and cfg.min_seen < 1.0:
        # A box on the corner of a sheet under motion blur: the five-sided regions' hypotheses
        # retried the same way (on seeds 80 and 82, 25 of 39 misses were 12-30 px streaks).
        hyps = [h for g in five for h in g
                if not sheet_candidates.touches_border(h.corners, image_bgr.shape, band)]
        _accept_blurred_border(image_bgr, hyps, band, cfg, K, found, dist, hidden=True)
    return path


def _stub_path(image_bgr: npt.NDArray[np.uint8], regions: list[sheet_candidates.Region],
               notched: list[sheet_candidates.Region], scale: float, band: float,
               cfg: SheetConfig, K: Array | None) -> '_Hidden':
    """The stub path (``sheet_stub``) of ``_accept_hidden``: one group of hypotheses, up to
    ``STUB_MAX_HYPS`` from ``regions`` and ``NOTCH_MAX_HYPS`` from the ``notched`` ones. Its
    hidden corner must not show the surface (``strict_cover``): a wall board's corner placed
    on the wall beside it, a wall patch between table legs, were stub sheets."""
    K_ = K if K is not None else _guess_K(cfg.focal_frac, image_bgr.shape)
    # (the notched regions with hypotheses of their own: a white object elsewhere in the
    # frame would otherwise use them all up)
    hyps = [h for rs, cap in ((regions, STUB_MAX_HYPS), (notched, NOTCH_MAX_HYPS))
            for h in sheet_stub.first_hypotheses(rs, scale, K_, cfg.stub_px, cap)]
    aspect = tuple(m.aspect for m in cfg.models())
    return _Hidden(
        [hyps],  # one stub sheet at most: a fallback
        lambda hyp, out: sheet_stub.finish(hyp, out, band, K_, aspect),
        rough_aspect=False, checked=sheet_stub.CHECKED, strict_cover=True,
        screen=lambda hyp, out: sheet_stub.finish(
            hyp, out, band, K_, aspect, sheet_stub.SCREEN_SLACK) is not None)


def _split_path(image_bgr: npt.NDArray[np.uint8], split: list[sheet_candidates.Region],
                scale: float, band: float, cfg: SheetConfig, K: Array | None,
                dist: Array | None) -> '_Hidden':
    """The split path (``sheet_split``) of ``_accept_hidden``: the five-sided outlines of
    regions joined with a part an occluder cut off, plain and sharp."""
    # (not merged like the masks' outlines: a rough corner a pixel off moves the hidden
    # corner's seen fractions across ``min_seen``)
    plain = [(r, sheet_partial.pentagon(r)) for r, _ in split]
    pents = [lines.full_px(p, scale) for r, pent in plain
             for p in (pent, sheet_partial.sharp_pentagon(r, pent)) if p is not None]
    # (narrowed after the rough tests ``_accept_partial`` applies: they see only corners,
    # which it keeps, and most hypotheses fail them)
    kept = _rough_kept([sheet_partial.hypotheses(p, SPLIT_SEEN * cfg.min_seen) for p in pents],
                       False, True, image_bgr.shape, band, cfg, K, dist)
    narrow = iter(sheet_split.narrowed_many([h for g in kept for h in g], image_bgr))
    return _Hidden([[next(narrow) for _ in g] for g in kept],
                   lambda hyp, out: sheet_split.finish(hyp, out, band, image_bgr),
                   seen_out=True, strict_cover=True, rough_tested=True)


def _follow_notches(found: list[Found], regions: list[sheet_candidates.Region], scale: float,
                    parts: list[sheet_candidates.Region]) -> None:
    """
    Replace the seen outline of each sheet found with a hidden corner by the region seen, the
    largest region lying within the sheet's quad (``_seen_region``): the quad cut along that
    region's outline where it runs inside the sheet (``sheet_partial.clipped``), when the
    cut's area is the region's within ``CLIP_AREA_TOL``. Else the largest region within a
    five-sided seen outline gives that outline's cut (``sheet_partial.notched``). (Pixel
    precision and recall: a box standing on a sheet's corner reaches into the hull of the
    part seen, and a chord between the sides' rough seen ends crossed the box and left seen
    sheet out.) A sheet seen in parts (the split path: a box across it) is outlined by
    each part's region (``_seen_parts``; ``parts``: the split path's cut-off parts).
    """
    by_area = sorted(regions, key=lambda r: -cv2.contourArea(r[0]))
    for i, (score, corners, outline, vs) in enumerate(found):
        if vs is None:
            continue
        if isinstance(outline, tuple):
            found[i] = (score, corners, _seen_parts(corners, by_area + parts, scale) or outline,
                        vs)
            continue
        area = cv2.contourArea(outline.astype(np.float32))
        seen = _seen_region(corners, by_area, scale, 0.5 * area)
        if seen is not None:
            cut = sheet_partial.clipped(corners, seen[0])
            if cut is not None and abs(cv2.contourArea(cut.astype(np.float32)) / seen[1]
                                       - 1.0) <= CLIP_AREA_TOL:
                found[i] = (score, corners, cut, vs)
                continue
        if len(outline) != 5:
            continue
        seen = _seen_region(outline, by_area, scale, 0.5 * area)
        if seen is not None:
            found[i] = (score, corners, sheet_partial.notched(outline, seen[0]), vs)


def _seen_parts(corners: Array, regions: list[sheet_candidates.Region], scale: float
                ) -> tuple[Array, ...]:
    """
    Return the outlines (``sheet_partial.snapped``) of the regions (largest first) lying
    within the quad ``corners`` (4, 2) px (as ``_seen_region``) and not within one taken
    already (different whiteness levels outline the same part), at most ``SEEN_PARTS``.
    """
    out: list[Array] = []
    for contour, _ in regions:
        seen = _seen_region(corners, [(contour, 0.0)], scale, 0.0)
        if seen is None:
            continue
        pts = seen[0]
        if any(cv2.pointPolygonTest(p.astype(np.float32), tuple(map(float, pts.mean(axis=0))),
                                    False) >= 0 for p in out):
            continue
        out.append(sheet_partial.snapped(corners, pts))
        if len(out) == SEEN_PARTS:
            break
    return tuple(out)


def _seen_region(poly: Array, regions: list[sheet_candidates.Region], scale: float,
                 min_area: float) -> tuple[Array, float] | None:
    """
    Return the dense outline (M, 2) px and area px of the first of ``regions`` (work image)
    of at least ``min_area`` px that lies within the convex polygon ``poly`` (K, 2) px
    (``NOTCH_INSIDE`` of its outline within ``NOTCH_SLACK_PX`` work px), or None.
    """
    centre = poly.mean(axis=0)
    ls = np.array([lines.line_through(a, b, centre)
                   for a, b in zip(poly, np.roll(poly, -1, axis=0))
                   if np.hypot(*(b - a)) > 1e-6])  # (a placed stub's cut is a corner)
    for contour, _ in regions:
        region_area = cv2.contourArea(contour) / scale ** 2
        if region_area < min_area:
            continue
        pts = lines.full_px(sheet_stub.dense(contour.reshape(-1, 2).astype(np.float64)), scale)
        if (lines.depths_inside(pts, ls).min(axis=1) >= -NOTCH_SLACK_PX / scale).mean() \
                >= NOTCH_INSIDE:
            return pts, region_area
    return None


def _accept_blurred_border(image_bgr: npt.NDArray[np.uint8], hyps: list[sheet_partial.Partial],
                           band: float, cfg: SheetConfig, K: Array | None, found: list[Found],
                           dist: Array | None, hidden: bool = False) -> None:
    """
    Retry sheets with a corner beyond the image border (``sheet_border``) as smeared by motion
    blur, as ``_accept_blurred`` does whole ones: a pan sweeps the sheet out of view, and the
    sides, refined along their seen parts, are found at the mid level of their ramps.
    ``hidden``: the hypotheses' corner is hidden by an occluder instead (``sheet_partial``),
    which must cover it (``sheet_checks.covered``, strict), and the aspect allows corner
    shifts larger by one over the smaller seen fraction of the sides at it (extrapolated
    from blurred sides).
    """
    hyps = [h for h in hyps if sheet_checks.aspect_ok(h.corners, image_bgr.shape, cfg, K,
                                                      cfg.rough_aspect_tol, dist)]
    for hyp in hyps[:BLUR_MAX_QUADS]:
        wide = _blur_band(hyp.corners, band, cfg)
        rough, n = sheet_partial.rough_sides(hyp)
        if not _motion_ramps(sides.ramp_widths(image_bgr, rough, hyp.seen_ends, wide, None,
                                               None, step_px=sides.blur_step(wide))):
            continue
        out = sides.refine_many(image_bgr, [rough], [hyp.seen_ends], (wide, 0.5 * wide), [n],
                                FIRST_PASS_SUPPORT, blurred=True)[0]
        fin = None if out is None else sheet_partial.finish(hyp, out, wide)
        if fin is None or not sheet_checks.big_enough(fin[5], image_bgr.shape, cfg):
            continue
        ramps = sides.ramp_widths(image_bgr, out[0], hyp.seen_ends, wide, fin[3], fin[4],
                                  step_px=sides.blur_step(wide))
        if not _motion_ramps(ramps):
            continue
        if sheet_checks.passes(image_bgr, fin[:5], cfg, K, hyp.seen_ends,
                               aspect_tol=_blur_aspect_tol(
                                   fin[0], ramps, cfg, K, dist,
                                   1.0 / float(hyp.seen_frac.min()) if hidden else 1.0),
                               dist=dist) and (not hidden or sheet_checks.covered(
                                   image_bgr, fin[0][3], fin[3], cfg, fin[4])):
            support = float(fin[1].mean())
            vs = np.array([support] * 3 + [0.5 * support * float(hyp.seen_frac.min())])
            found.append((float(vs.mean()), fin[0], fin[5], vs))
            return


@dataclass(frozen=True, eq=False)
class _Hidden:
    """
    One hidden-corner path for ``_accept_partial``: hypotheses grouped by seen region,
    ``finish`` turning refined sides into corners, whether the rough corners' aspect is
    tested, the sides that must pass the first refinement pass (None: all), a screen
    after it (None: none), and whether ``finish`` also gives the seen side ends for the
    tests (its seventh result, instead of the hypothesis's) and the seen outline in parts
    (its eighth); ``strict_cover``: the hidden corner must not show the surface or a blend
    of it and the sheet either (``sheet_checks.covered``).
    """

    groups: list[list[sheet_partial.Partial]]
    finish: Callable[[sheet_partial.Partial, sides.Refined], Refined6 | None]
    rough_aspect: bool = True
    checked: npt.NDArray[np.intp] | None = None
    screen: Callable[[sheet_partial.Partial, sides.Refined], bool] | None = None
    seen_out: bool = False
    strict_cover: bool = False
    border: bool = False
    rough_tested: bool = False  # the hypotheses passed ``_rough_ok`` already


def _accept_partial(image_bgr: npt.NDArray[np.uint8], paths: list[_Hidden], band: float,
                    cfg: SheetConfig, K: Array | None, found: list[Found],
                    fine_bands: tuple[float, ...] = sheet_partial.FINE_BANDS,
                    dist: Array | None = None) -> int | None:
    """
    Try every hidden-corner hypothesis of each group (one seen region); keep the best
    supported per group. The paths are tried in order until one finds a sheet, but their
    hypotheses are refined together, one ``sides.refine_many`` call (per pass) for all.
    Return the index of the path that found a sheet (``found`` is empty on entry), or None.
    ``rough_aspect``: test the aspect of the rough corners (not for stubs, whose rough hidden
    corner comes from short rough sides; ``_passes`` applies it and the floor-tile rule to the
    refined corners anyway). ``checked`` are the sides that must pass the first refinement
    pass (None: all), ``fine_bands`` the passes after it, ``finish`` turns the refined sides
    into corners (``sheet_partial.finish``); ``screen`` drops hypotheses after the first pass.

    The extrapolated corner scores half the sheet's support times the smaller seen fraction of
    its two sides; the sheet's score is the mean over its corners.
    """
    # A corner beyond the border has no occluder to show for the cut (tiles), except on the
    # border path, whose cut runs along the border (``sheet_border``).
    groups = [path.groups if path.rough_tested else _rough_kept(
        path.groups, path.border, path.rough_aspect, image_bgr.shape, band, cfg, K, dist)
        for path in paths]
    jobs = [(path, h) for path, gs in zip(paths, groups) for g in gs for h in g]
    rough = [sheet_partial.rough_sides(h) for _, h in jobs]
    refined = iter(sides.refine_many(
        image_bgr, [r for r, _ in rough], [h.seen_ends for _, h in jobs], (band,) + fine_bands,
        [n for _, n in rough], FIRST_PASS_SUPPORT, [p.checked for p, _ in jobs],
        lambda c, out: jobs[c][0].screen is None or jobs[c][0].screen(jobs[c][1], out)))
    for at, (path, path_groups) in enumerate(zip(paths, groups)):
        if found:
            return at - 1  # (a path after one that found a sheet is not tried)
        for group in path_groups:
            best: tuple[float, Found] | None = None
            for hyp in group:
                sides_out = next(refined)
                out = None if sides_out is None else path.finish(hyp, sides_out)
                seen = hyp.seen_ends if out is None or not path.seen_out else out[6]
                if out is None or not sheet_checks.big_enough(out[5], image_bgr.shape, cfg) or \
                        not sheet_checks.passes(image_bgr, out[:5], cfg, K, seen, dist=dist) or \
                        not (path.border or sheet_checks.covered(
                            image_bgr, out[0][3], out[3], cfg,
                            out[4] if path.strict_cover else None)):
                    continue
                support = float(out[1].mean())
                vs = np.array([support] * 3 + [0.5 * support * float(hyp.seen_frac.min())])
                if best is None or support > best[0]:
                    best = (support, (float(vs.mean()), out[0],
                                      out[7] if path.seen_out else out[5], vs))
            if best is not None and all(np.abs(best[1][1] - f[1]).max() > 4.0 for f in found):
                found.append(best[1])
    return len(paths) - 1 if found else None


def _rough_ok(hyp: sheet_partial.Partial, border: bool, rough_aspect: bool,
              shape: tuple[int, ...], band: float, cfg: SheetConfig, K: Array | None,
              dist: Array | None) -> bool:
    """``_accept_partial``'s tests of a hypothesis's rough corners: none within ``band`` of
    the image border (unless on the ``border`` path) and, with ``rough_aspect``, the aspect
    (``_rough_aspect_ok``, as for a whole sheet: a small sheet's rough corner next to a
    blunted one is a work pixel or more off)."""
    return (border or not sheet_candidates.touches_border(hyp.corners, shape, band)) and \
        (not rough_aspect or _rough_aspect_ok(hyp.corners, shape, band, cfg, K, dist))


def _rough_kept(groups: list[list[sheet_partial.Partial]], border: bool, rough_aspect: bool,
                shape: tuple[int, ...], band: float, cfg: SheetConfig, K: Array | None,
                dist: Array | None) -> list[list[sheet_partial.Partial]]:
    """The hypotheses of each group that pass ``_rough_ok``, all tested at once
    (``_rough_oks``)."""
    oks = iter(_rough_oks([h for g in groups for h in g], border, rough_aspect, shape, band,
                          cfg, K, dist))
    return [[h for h in g if next(oks)] for g in groups]


def _rough_oks(hyps: list[sheet_partial.Partial], border: bool, rough_aspect: bool,
               shape: tuple[int, ...], band: float, cfg: SheetConfig, K: Array | None,
               dist: Array | None) -> list[bool]:
    """``_rough_ok`` of many hypotheses, their aspect errors computed together (with
    intrinsics: ``sheet_checks.aspect_errors``, bit for bit the same; on page-less outdoor
    frames the split path tests ~90 a frame)."""
    if K is None or not rough_aspect or len(hyps) < 2:
        return [_rough_ok(h, border, rough_aspect, shape, band, cfg, K, dist) for h in hyps]
    corners = np.array([h.corners for h in hyps])
    errs = sheet_checks.aspect_errors(corners, cfg, K, dist)
    return [(border or not sheet_candidates.touches_border(c, shape, band)) and
            _rough_aspect_ok(c, shape, band, cfg, K, dist, float(e))
            for c, e in zip(corners, errs)]


def _guess_K(focal_frac: float, shape: tuple[int, ...]) -> Array:
    """Return intrinsics from a focal length guess (``focal_frac`` of the larger side)."""
    h, w = shape[:2]
    f = focal_frac * max(h, w)
    return np.array([[f, 0.0, (w - 1) / 2.0], [0.0, f, (h - 1) / 2.0], [0.0, 0.0, 1.0]])


def _detection(f: Found, model: targets.SheetModel) -> targets.TargetDetection:
    score, corners, outline, vertex_scores = f
    order = _order(corners)
    return targets.TargetDetection(
        target_type='sheet', name=model.name, vertices_px=corners[order],
        vertex_ids=np.arange(4, dtype=np.int64), edges=model.edges(),
        polygons=tuple(('sheet', p) for p in (
            (corners[order],) if vertex_scores is None else
            outline if isinstance(outline, tuple) else (outline,))),
        score=score, vertex_scores=None if vertex_scores is None else vertex_scores[order])
