"""
Sheet candidates: rough quadrilaterals (and five-sided regions, a sheet with a corner hidden)
from whiteness and colour-edge masks of a downscaled work image.

Whiteness (the smallest of B, G, R, high only on white, unsaturated surfaces) above a few
thresholds, and regions enclosed by colour edges; each region is filtered like a cube face
(area >= 0.005 of the image, roundness eq. 1, area close to the convex hull) and simplified to
four corners (``detect_sheet`` refines and tests them).
"""
from typing import TYPE_CHECKING

import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core import lines, sheet_partial

if TYPE_CHECKING:
    from absscale_ros.core.detect_sheet import SheetConfig

Array = npt.NDArray[np.float64]
Region = tuple[npt.NDArray[np.int32], float]  # a contour, and how far its outline lies outside
ROUGH_AREA_SLACK = 0.7  # rough regions may be this much smaller than the area threshold
# Whiteness levels between Otsu's threshold (0) and the 99.5th percentile (1): the last just
# under the brightest 0.5 % of the image, which an eligible sheet covers, so a sheet on a
# surface almost as white (a light table top) is cut out of it.
LEVELS = (0.0, 1.0 / 3.0, 2.0 / 3.0, 0.85)
# ... for whole quadrilaterals only: a region cut at the last level is a pixel or two smaller, and
# its five-sided outline, listed first (whitest), misled the hidden-corner paths (unseen seeds).
QUAD_ONLY_MASK = 3
FREE_MASK = len(LEVELS)  # index of the edge-free regions in ``masks``
SAT_SLACK = 0.1  # the region's mean colour may be this much more saturated than its sides'
RING_PX = (3, 7)  # the ring around a region for its contrast, work px (past a blurred edge)
RING_STEP = 3  # every third ring pixel is enough for its median
RING_CONTRAST = 2.0  # of ``min_contrast``; sheets in the simulator show 4x or more
PENT_MIN_SOLIDITY = 0.75  # a region with a corner cut off by an occluder's notch is less convex
FREE_INSET_PX = 2.0  # a 3x3-dilated Canny line keeps edge-free regions this far inside
COLOUR_SEEDS = 3  # whitest regions whose own colour is looked for again (``colour_quads``)
COLOUR_TOLS = (12, 20, 30)  # largest channel difference from that colour, 0-255
SPLIT_MIN_AREA = 0.1  # of the rough area threshold: the smallest cut-off part of a sheet joined
# ... looked for again, when no part of the cleaned mask is near, in the whiteness mask closed
# only (``_light_parts``): a sliver of page beyond a box, a few work px wide, does not survive
# the twice-repeated 3x3 opening
SPLIT_LIGHT_MIN_AREA = 0.05
CHROMA_CLOSE_PX = 5  # disc closing text away before the chroma thresholds (``chroma_quads``)
CHROMA_OFFSETS = (-4, 0, 4)  # b* thresholds around its Otsu threshold (``chroma_quads``)
DETACH_PX = 9  # diameter of the opening that cuts bright blobs off a page (``detached_quads``)


def shrink(image: npt.NDArray[np.uint8], scale: float,
           half: npt.NDArray[np.uint8] | None = None) -> npt.NDArray[np.uint8]:
    """
    Return ``image`` resized by ``scale`` (<= 1): box-filtered halvings (OpenCV's fast
    integer-factor path), then bilinear to the exact size; about 6x less CPU than one
    ``INTER_AREA`` resize by a non-integer factor, and as free of aliasing. ``half``: the first
    halving when another detector made it already.
    """
    h, w = image.shape[:2]
    size = (round(w * scale), round(h * scale))
    out = image
    if half is not None and half.shape[:2] == (h // 2, w // 2) and \
            w >= 2 * size[0] and h >= 2 * size[1]:
        out = half
    while out.shape[1] >= 2 * size[0] and out.shape[0] >= 2 * size[1]:
        out = cv2.resize(out, (out.shape[1] // 2, out.shape[0] // 2),
                         interpolation=cv2.INTER_AREA)
    if out.shape[:2] == (size[1], size[0]):
        return out
    return cv2.resize(out, size, interpolation=cv2.INTER_LINEAR)


def whiteness(image_bgr: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]:
    """Return the (H, W) uint8 per-pixel minimum over B, G, R: high only on white."""
    b, g, r = cv2.split(image_bgr)
    return cv2.min(cv2.min(b, g), r)


def masks(work_bgr: npt.NDArray[np.uint8], work_white: npt.NDArray[np.uint8],
          cfg: 'SheetConfig') -> list[npt.NDArray[np.uint8]]:
    """
    Return binary candidate masks on the work image, cleaned (``_clean``): ``white_masks``
    then ``edge_masks``.
    """
    return white_masks(work_white) + edge_masks(work_bgr, cfg)


def white_masks(work_white: npt.NDArray[np.uint8]) -> list[npt.NDArray[np.uint8]]:
    """
    Whiteness above a few thresholds (Otsu and higher ``LEVELS``), cleaned: a sheet that is
    clearly brighter than its surface.
    """
    # Flat morphology commutes with thresholding: the whiteness image is cleaned once, and
    # each level's mask is the cleaned mask of that level.
    clean_white = _clean(work_white)
    # (cv2.threshold on uint8 tests > floor(t): the same as > t)
    return [cv2.threshold(clean_white, t, 1, cv2.THRESH_BINARY)[1]
            for t in white_levels(work_white)]


def white_levels(work_white: npt.NDArray[np.uint8]) -> list[float]:
    """The whiteness thresholds of ``white_masks``: Otsu's and the higher ``LEVELS``."""
    otsu, _ = cv2.threshold(work_white, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    hist = np.cumsum(cv2.calcHist([work_white], [0], None, [256], [0, 256]).ravel())
    top = float(np.searchsorted(hist, 0.995 * hist[-1]))  # 99.5th percentile
    return [otsu + f * (top - otsu) for f in LEVELS]


def edge_masks(work_bgr: npt.NDArray[np.uint8], cfg: 'SheetConfig'
               ) -> list[npt.NDArray[np.uint8]]:
    """
    Regions enclosed by colour edges (Canny on BGR), cleaned: a sheet that differs from the
    surface mostly in tint, where no grey threshold separates them. (The colour Canny is a
    third of the candidate search: ``candidates`` makes these only when asked.) They are made
    on the work image shrunk to two thirds and scaled back up (nearest): the colour Canny
    costs as much as the rest of a frame without a sheet, and rough outlines serve (the sides
    are refined on the full image). The same figures on the tuning and unseen bags (sheet
    precision and recall within 0.001 %), SmartDoc pages 4/6 either way.
    """
    h, w = work_bgr.shape[:2]
    small = cv2.resize(work_bgr, (w * 2 // 3, h * 2 // 3), interpolation=cv2.INTER_AREA)
    return [cv2.resize(m, (w, h), interpolation=cv2.INTER_NEAREST)
            for m in _edge_masks(small, cfg)]


def _edge_masks(work_bgr: npt.NDArray[np.uint8], cfg: 'SheetConfig'
                ) -> list[npt.NDArray[np.uint8]]:
    """``edge_masks`` at the size of ``work_bgr``."""
    blurred = cv2.GaussianBlur(work_bgr, (3, 3), 0)
    edges = cv2.Canny(blurred, cfg.canny_low, cfg.canny_high)
    edges = cv2.dilate(edges, np.ones((3, 3), np.uint8))
    free = cv2.threshold(edges, 0, 1, cv2.THRESH_BINARY_INV)[1]
    out = [_clean(free)]  # edge-free regions: a sheet's blank areas
    # Everything the image border cannot reach without crossing an edge: objects on the
    # surface, with their text and drawings filled in.
    flood = np.pad(free, 1, constant_values=1)
    cv2.floodFill(flood, None, (0, 0), 2)
    out.append(_clean(cv2.compare(flood[1:-1, 1:-1], 2, cv2.CMP_NE) // 255))
    return out


def _clean(mask: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]:
    """
    Closing heals thin dark lines across the sheet (text, a cable); the paper's 3x3 opening,
    twice, then drops thin bridges to neighbouring objects. (Binary or grey: flat.)
    """
    mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
    return cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8), iterations=2)


class Candidates:
    """
    Rough (4, 2) quadrilaterals, work-image px, from the candidate masks, and every large
    ``plausible`` region, whitest first (for the hidden-corner paths: only needed when no
    quadrilateral passes). The whiteness masks are searched at once; ``edge_regions`` adds
    the colour-edge masks' quads (returned, new ones only) and regions, in the mask order of
    ``masks``: with both, quads and regions are those of all masks searched together.
    """

    def __init__(self, work_bgr: npt.NDArray[np.uint8], cfg: 'SheetConfig') -> None:
        self.work_bgr, self.cfg = work_bgr, cfg
        work_white = whiteness(work_bgr)
        self._work_white = work_white
        # ``_light_parts``, once needed, and the regions waiting for them
        self._pending: list[tuple[npt.NDArray[np.int32], int, float, float]] = []
        self._closed_white: npt.NDArray[np.uint8] | None = None
        self._levels: list[float] = []
        self._light: dict[int, list[tuple[npt.NDArray[np.int32], tuple[int, int, int, int]]]] = {}
        self.quads: list[Array] = []
        self._regions: list[Region] = []
        self._whites: list[float] = []
        self._edges_done = False
        self._split: list[tuple[npt.NDArray[np.int32], float]] = []
        self._split_parts: list[npt.NDArray[np.int32]] = []  # the parts joined to them
        self._border: list[Region] = []
        self._notched: list[tuple[Region, float]] = []  # (with their whiteness)
        self._add(white_masks(work_white), 0)
        self._white_count = len(self._regions)

    def edge_quads(self) -> list[Array]:
        """Search the colour-edge masks too; return the quads they add."""
        if self._edges_done:
            return []
        self._edges_done = True
        start = len(self.quads)
        self._add(edge_masks(self.work_bgr, self.cfg), FREE_MASK)
        return self.quads[start:]

    @property
    def regions(self) -> list[Region]:
        """Every large ``plausible`` region of the masks searched so far, whitest first."""
        return _whitest_first(self._regions, self._whites)  # where a sheet is likeliest

    @property
    def white_regions(self) -> list[Region]:
        """
        ``regions`` of the whiteness masks only, for the hidden-corner paths: on the tuning
        and unseen bags and the SmartDoc frames no sheet with a hidden corner came from a
        colour-edge region, whose hypotheses cost about a fifth of a frame without a sheet.
        """
        return _whitest_first(self._regions[:self._white_count],
                              self._whites[:self._white_count])

    def _add(self, masks_: list[npt.NDArray[np.uint8]], first: int) -> None:
        work_bgr, cfg, quads = self.work_bgr, self.cfg, self.quads
        shape = work_bgr.shape[:2]
        # Opening and the contour through boundary pixel centres shrink a small region by a
        # pixel all round: a loose test here, the exact one on the refined full-resolution
        # corners.
        min_area = ROUGH_AREA_SLACK * cfg.min_area_frac * shape[0] * shape[1]
        for i, mask in enumerate(masks_, first):
            contours, tree = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
            # An edge-free region stops short of the outline by the dilated edge's half width.
            grow = FREE_INSET_PX if i == FREE_MASK else 0.0
            parts = None  # this mask's small regions (``_cut_off_parts``), once needed
            for c, node in zip(contours, tree[0] if tree is not None else ()):
                solidity = region_shape(c, min_area, cfg)
                notch = 0.0 < solidity and cfg.notch_solidity <= solidity < PENT_MIN_SOLIDITY
                if solidity < PENT_MIN_SOLIDITY and not notch:
                    continue  # too small, too round or too long, or far from convex
                # A region the border cuts has a side along it with no edge to refine: not for
                # the hidden-corner paths (their hypotheses fail or are refused there), only
                # for the corner beyond the border (``sheet_border``, whiteness masks).
                x, y, w, h = cv2.boundingRect(c)
                cut = not (min(x, y) > 1 and x + w < shape[1] - 1 and y + h < shape[0] - 1)
                if notch:
                    if not cut and i < QUAD_ONLY_MASK:
                        parts = self._add_notched(c, grow, i, contours, min_area, parts)
                    continue
                # (Colour-edge regions only serve the line mode's colour seeds: ``white_regions``.)
                inner = not cut and i != QUAD_ONLY_MASK and (i < FREE_MASK or cfg.line_candidates)
                if cut and i < QUAD_ONLY_MASK:
                    self._border.append((c, grow))
                quad = lines.rough_quad(c) if solidity >= cfg.min_solidity else None
                quad = None if quad is None else offset(quad, grow)
                # A sheet cut by the image border has no trustworthy corners, and another
                # mask's outline of a quad already kept is not tested again.
                new = quad is not None and not touches_border(quad, shape) and \
                    all(np.abs(quad - q).max() > 2.0 for q in quads)
                if not (inner or new):
                    continue  # nothing to use it for: spare the plausibility test
                white = plausible(work_bgr, c, cfg)
                if white is None:
                    continue
                if inner:
                    self._regions.append((c, grow))
                    self._whites.append(white)
                    if i < FREE_MASK and cfg.split_gap > 0.0:
                        parts = _cut_off_parts(contours, min_area) if parts is None else parts
                        if not self._add_split(c, parts, white):
                            self._pending.append((c, i, white, min_area))  # ``split_regions``
                if new and quad is not None:
                    quads.append(quad)

    def _add_notched(self, contour: npt.NDArray[np.int32], grow: float, mask: int,
                     contours: 'tuple[npt.NDArray[np.int32], ...]', min_area: float,
                     parts: list[tuple[npt.NDArray[np.int32], tuple[int, int, int, int]]] | None
                     ) -> list[tuple[npt.NDArray[np.int32], tuple[int, int, int, int]]] | None:
        """
        Keep a region of a whiteness mask that is too concave for the other hidden-corner
        paths (``notched_regions``) when ``plausible``, and try it for the split path like
        the convex ones (a box standing over a sheet's corner and its middle notches the
        larger part seen and cuts a corner off: seed 85). Return this mask's ``parts``.
        """
        white = plausible(self.work_bgr, contour, self.cfg)
        if white is None:
            return parts
        self._notched.append(((contour, grow), white))
        if self.cfg.split_gap > 0.0:
            parts = _cut_off_parts(contours, min_area) if parts is None else parts
            if not self._add_split(contour, parts, white):
                self._pending.append((contour, mask, white, min_area))
        return parts

    @property
    def notched_regions(self) -> list[Region]:
        """
        Regions of the whiteness masks (those ``white_regions`` come from) whose solidity is
        below ``PENT_MIN_SOLIDITY`` but at least ``cfg.notch_solidity``, whitest first: a box
        standing on a sheet's corner whose own corner reaches deep into the part seen (seed
        61: 0.62-0.69). Their five-sided outlines would be a sheet's hull cut by a chord
        across the box, so they are tried as a stub (``sheet_stub``), and joined with a part
        the box cut off (``split_regions``).
        """
        return _whitest_first([r for r, _ in self._notched], [w for _, w in self._notched])

    def _add_split(self, contour: npt.NDArray[np.int32],
                   parts: list[tuple[npt.NDArray[np.int32], tuple[int, int, int, int]]],
                   white: float) -> bool:
        """
        Add, for the hidden-corner paths only, ``contour`` joined with each small region of
        the same mask (``parts``) near it: an object standing on a sheet's corner can cut a
        bit of the sheet off (one seen corner and a stretch of the sides at it), and the two
        parts' joint outline is the five-sided region of a sheet with its corner hidden.
        A region near more than ``cfg.split_max_parts`` parts is joined with none: a box cuts
        a sheet in two or three, while a light paver or tile has a dozen alike around it (on
        page-less outdoor frames 92 % of the joins, each a refined hypothesis or more).
        Return whether one was added, or the region was refused so.
        """
        size = np.sqrt(cv2.contourArea(contour))
        x, y, w, h = cv2.boundingRect(contour)
        near = []
        for other, (ox, oy, ow, oh) in parts:
            if other is contour:
                continue
            gap = max(ox - (x + w), x - (ox + ow), oy - (y + h), y - (oy + oh))
            if gap > self.cfg.split_gap * size:
                continue
            # (its nearest point no farther than that: the first one found will do)
            if any(cv2.pointPolygonTest(contour, (float(px), float(py)), True)
                   >= -self.cfg.split_gap * size for px, py in other.reshape(-1, 2)):
                near.append(other)
                if len(near) > self.cfg.split_max_parts:
                    return True  # texture (paving, tiles): not joined, nor looked at again
        for other in near:
            self._split.append((np.vstack([contour, other]), white))
            self._split_parts.append(other)
        return bool(near)

    def _light_parts(self, level: int, min_area: float
                     ) -> list[tuple[npt.NDArray[np.int32], tuple[int, int, int, int]]]:
        """
        ``_cut_off_parts`` of whiteness mask ``level`` closed but not opened, down to
        ``SPLIT_LIGHT_MIN_AREA`` of the rough area (the closed whiteness made once per
        frame; each level's parts once). On seed 57, the Otsu level's alone found 5 sheets
        of 41 fewer.
        """
        if self._closed_white is None:
            self._closed_white = cv2.morphologyEx(self._work_white, cv2.MORPH_CLOSE,
                                                  np.ones((5, 5), np.uint8))
            self._levels = white_levels(self._work_white)
        if level not in self._light:
            mask = cv2.threshold(self._closed_white, self._levels[level], 1,
                                 cv2.THRESH_BINARY)[1]
            contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
            self._light[level] = [
                (c, cv2.boundingRect(c)) for c in contours
                if SPLIT_LIGHT_MIN_AREA * min_area <= cv2.contourArea(c) < min_area]
        return self._light[level]

    @property
    def border_regions(self) -> list[Region]:
        """Regions of the whiteness masks the image border cuts (``sheet_border``: not yet
        tested ``plausible``, which costs more than their hypotheses)."""
        return self._border

    @property
    def split_regions(self) -> list[Region]:
        """``white_regions`` joined with a nearby cut-off part (``_add_split``), whitest first."""
        # Regions no part of the cleaned masks joined: with the closed masks' parts (only
        # now: the hidden-corner paths ask for them, on frames without a whole sheet).
        # (A region of a higher level within a pixel of one already joined adds only copies.)
        boxes: list[npt.NDArray[np.int64]] = []
        for c, level, white, min_area in self._pending:
            box = np.array(cv2.boundingRect(c))
            if any(np.abs(box - b).max() <= 1 for b in boxes):
                continue
            if self._add_split(c, self._light_parts(level, min_area), white):
                boxes.append(box)
        self._pending = []
        return [(c, 0.0) for c in _whitest_first([c for c, _ in self._split],
                                                 [w for _, w in self._split])]

    @property
    def split_parts(self) -> list[Region]:
        """The cut-off parts ``split_regions`` joined (after that was asked for): a sheet's
        seen outline is the union of its parts (``detect_sheet._follow_notches``)."""
        return [(c, 0.0) for c in self._split_parts]


def _whitest_first(items: list, whites: list[float]) -> list:
    """``items`` by their whiteness, whitest first (ties in their order)."""
    return [items[i] for i in np.argsort(-np.array(whites, float), kind='stable')]


def _cut_off_parts(contours: 'tuple[npt.NDArray[np.int32], ...]', min_area: float
                   ) -> list[tuple[npt.NDArray[np.int32], tuple[int, int, int, int]]]:
    """The regions of one mask small enough to be a part of a sheet an object cut off
    (``Candidates._add_split``), with their bounding boxes: measured once per mask, not once
    per region they may join."""
    return [(c, cv2.boundingRect(c)) for c in contours
            if SPLIT_MIN_AREA * min_area <= cv2.contourArea(c) < min_area]


def candidates(work_bgr: npt.NDArray[np.uint8], cfg: 'SheetConfig'
               ) -> tuple[list[Array], list[Region]]:
    """
    Return rough (4, 2) quadrilaterals, work-image px, of all candidate masks, and every
    large ``plausible`` region, whitest first (``Candidates`` of every mask).
    """
    cands = Candidates(work_bgr, cfg)
    cands.edge_quads()
    return cands.quads, cands.regions


def colour_quads(work_bgr: npt.NDArray[np.uint8], regions: list[Region], cfg: 'SheetConfig'
                 ) -> list[Array]:
    """
    Return rough (4, 2) quadrilaterals, work px, of the regions of one colour: the median
    colour of each of the ``COLOUR_SEEDS`` whitest regions, within each of ``COLOUR_TOLS``.
    On a textured or cluttered desk a page joins bright patches around it in every whiteness
    mask; those are rarely its own tint as well.
    """
    quads: list[Array] = []
    for contour, _ in regions[:COLOUR_SEEDS]:
        seed = np.zeros(work_bgr.shape[:2], np.uint8)
        cv2.drawContours(seed, [contour], 0, 1, -1)
        colour = np.median(work_bgr[seed > 0], axis=0).astype(np.int16)
        diff = np.abs(work_bgr.astype(np.int16) - colour).max(axis=2)
        for tol in COLOUR_TOLS:
            _add_quads(quads, _clean((diff <= tol).astype(np.uint8)), work_bgr, cfg)
    return quads


def detached_quads(work_bgr: npt.NDArray[np.uint8], cfg: 'SheetConfig') -> list[Array]:
    """
    Return rough (4, 2) quadrilaterals, work px, of the candidate masks opened by a disc of
    ``DETACH_PX``: bright texture touching a page (wood grain, a magazine) joins it through
    necks a few pixels wide that the 3x3 opening keeps. A page's rough corners survive: they
    are fitted to its straight sides, not taken from the rounded outline.
    """
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (DETACH_PX, DETACH_PX))
    quads: list[Array] = []
    for mask in masks(work_bgr, whiteness(work_bgr), cfg):
        _add_quads(quads, cv2.morphologyEx(mask, cv2.MORPH_OPEN, disc), work_bgr, cfg,
                   plausible_only=True)
    return quads


def chroma_quads(work_bgr: npt.NDArray[np.uint8], cfg: 'SheetConfig') -> list[Array]:
    """
    Return rough (4, 2) quadrilaterals, work px, of the regions on either side of Otsu
    thresholds of the blue-yellow chroma (CIELAB b*, after closing away dark text): white
    paper is bluer than a warm desk of the same brightness (or yellower than a cold one).
    """
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (CHROMA_CLOSE_PX,) * 2)
    b = cv2.cvtColor(cv2.morphologyEx(work_bgr, cv2.MORPH_CLOSE, disc), cv2.COLOR_BGR2LAB)[..., 2]
    quads: list[Array] = []
    otsu, _ = cv2.threshold(b, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    for t in (otsu + d for d in CHROMA_OFFSETS):
        for flag in (cv2.THRESH_BINARY_INV, cv2.THRESH_BINARY):
            _add_quads(quads, _clean(cv2.threshold(b, t, 1, flag)[1]), work_bgr, cfg)
    return quads


def _add_quads(quads: list[Array], mask: npt.NDArray[np.uint8],
               work_bgr: npt.NDArray[np.uint8], cfg: 'SheetConfig',
               plausible_only: bool = False) -> None:
    """
    Append to ``quads`` the rough quadrilateral of every sheet-shaped region of ``mask`` not
    cut by the image border and not already in ``quads`` (``plausible_only``: of
    ``plausible`` regions only).
    """
    min_area = ROUGH_AREA_SLACK * cfg.min_area_frac * work_bgr.shape[0] * work_bgr.shape[1]
    for c in cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)[0]:
        if region_shape(c, min_area, cfg) < cfg.min_solidity:
            continue
        quad = lines.rough_quad(c)
        if quad is not None and not touches_border(quad, work_bgr.shape) and \
                all(np.abs(quad - q).max() > 2.0 for q in quads) and \
                (not plausible_only or plausible(work_bgr, c, cfg) is not None):
            quads.append(quad)


def pentagons(regions: list[Region], sharp: bool = False) -> list[Array]:
    """
    Return the distinct (5, 2) pentagons (a sheet with a corner cut off) of ``regions``:
    ``sheet_partial.pentagon``, or with ``sharp`` ``sheet_partial.sharp_pentagon``.
    """
    pents: list[Array] = []
    for contour, grow in regions:
        pent = sheet_partial.pentagon(contour)
        pent = sheet_partial.sharp_pentagon(contour, pent) if sharp else pent
        pent = None if pent is None else offset(pent, grow)
        if pent is not None and all(np.abs(pent - q).max() > 2.0 for q in pents):
            pents.append(pent)
    return pents


def plausible(work_bgr: npt.NDArray[np.uint8], contour: npt.NDArray[np.int32],
              cfg: 'SheetConfig') -> float | None:
    """
    Return a region's whiteness (smallest channel of its mean colour) when that colour is
    unsaturated enough and differs from the ring
    just around it: cheap work-image versions of the detector's one-colour and contrast tests,
    so wood, coloured objects and floor tiles (the same colour beyond the grout) go before
    the full-resolution refinement.
    """
    x, y, w, h = cv2.boundingRect(contour)
    m = RING_PX[1]
    x0, y0 = max(x - m, 0), max(y - m, 0)
    x1, y1 = min(x + w + m, work_bgr.shape[1]), min(y + h + m, work_bgr.shape[0])
    inside = np.zeros((y1 - y0, x1 - x0), np.uint8)
    cv2.drawContours(inside, [contour - np.array([x0, y0], np.int32)], 0, 1, -1)
    roi = work_bgr[y0:y1, x0:x1]
    mean_in = np.array(cv2.mean(roi, inside)[:3])
    if mean_in.max() - mean_in.min() > (cfg.max_saturation + SAT_SLACK) * max(mean_in.max(), 1.0):
        return None
    ring_px = roi[cv2.dilate(inside, _square(m)) > cv2.dilate(inside, _square(RING_PX[0]))]
    ring_px = ring_px[::RING_STEP]
    if not len(ring_px):
        return None  # nothing around it in the image: no surface it lies on
    ring = np.median(ring_px, axis=0)  # the median skips a grout line in the ring
    if np.linalg.norm(mean_in - ring) < RING_CONTRAST * cfg.min_contrast:
        return None
    return float(mean_in.min())


def offset(poly: Array, dist_px: float) -> Array | None:
    """Return a convex polygon (N, 2) with every side moved ``dist_px`` outwards, or None."""
    if dist_px == 0.0:
        return poly
    ls = lines.side_lines(poly)
    for ln in ls:
        ln[2] -= dist_px
    out = [lines.intersect(ls[k - 1], ls[k]) for k in range(len(ls))]
    return None if any(p is None for p in out) else np.array(out)


def touches_border(quad: Array, shape: tuple[int, ...], margin: float = 1.5) -> bool:
    """Return True when a polygon reaches within ``margin`` px of the image border."""
    h, w = shape[:2]
    return bool((quad.min() < margin) or (quad[:, 0].max() > w - 1 - margin)
                or (quad[:, 1].max() > h - 1 - margin))


def region_shape(contour: npt.NDArray[np.int32], min_area: float, cfg: 'SheetConfig') -> float:
    """
    Apply the area and roundness (eq. 1) tests; return the region's area over its convex hull
    area (solidity, the convexity test) when they pass, else 0.
    """
    area = cv2.contourArea(contour)
    if area < min_area:
        return 0.0
    roundness = 4.0 * np.pi * area / max(cv2.arcLength(contour, True), 1e-9) ** 2  # eq. 1
    if not cfg.roundness_min <= roundness <= cfg.roundness_max:
        return 0.0
    return area / max(cv2.contourArea(cv2.convexHull(contour)), 1e-9)


def _square(radius: int) -> npt.NDArray[np.uint8]:
    return np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)  # separable: fast
