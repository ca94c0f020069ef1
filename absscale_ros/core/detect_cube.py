"""
Tri-colour cube detection: the paper's Step 1 ("Detection of the cube's vertices").

Per face colour an HSV mask, a 3x3 opening applied twice, connected components, and the
paper's three tests: area >= 0.005 of the image, roundness (eq. 1) in [0.1, 0.85], area close
to the convex hull. A surviving face is simplified to four sides; each side is located by a
Hough vote at 2 degree resolution over the face outline (a 3 px wide rho strip tolerates the
slight curvature of lens distortion) and refined to sub-pixel on the full-resolution colour
mask. Corners of different faces that meet are merged into one cube vertex: the point nearest
(least squares) to all the edges meeting there, as the paper does when three edges do not
meet exactly. Faces sharing an edge form one cube. A face the image border cuts along one
side keeps its other sides and the corners between them; sharp, it also poses the cube,
completed from its whole side (``cube_geometry.complete_cut``); so does a face a post in front
cuts along its edge (``cube_occluder``), and a face the border cuts across a corner keeps its
seen corners (``cube_border``); two pieces of a face a post splits are joined into it. When
no cube is found, the regions that fail the tests or the refinement are cut into faces
(``cube_split``: a face joined in the mask with a box of its own colour) and the cube looked
for again.
"""
from dataclasses import dataclass
import functools

import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core import (cube_assembly, cube_border, cube_fill, cube_geometry,
                               cube_occluder, cube_prune, cube_split, cube_strips, cube_tip,
                               lines, sides, targets)

Array = npt.NDArray[np.float64]
# The blur retry (``_smeared``): a face must ramp over this share of the band, and alike on
# opposite sides in a band wider than BLUR_FREE_BAND_PX.
BLUR_MIN_RAMP_FRAC = 0.25
BLUR_FREE_BAND_PX = 12.0
BORDER_PX = 2.0  # a rough face corner this close to the image border lies on it
CUT_MAX_RAMP_PX = 3.0  # a sharp side ramps over 1-2 px (25-75 %): sharper poses a cut face
NEXT = [1, 2, 3, 0]  # the next corner of each of a quadrilateral's four


@dataclass(frozen=True)
class CubeConfig:
    """
    Thresholds of the cube detector; defaults are the paper's where it gives one.

    Hue ranges are in degrees [0, 360) and wrap when ``lo > hi`` (red). The paper's Fig. 2
    colours are not given numerically; the ranges are wide enough for shade and sun.

    :param min_area_frac: smallest cube area (its visible faces) over image area (paper: 0.005):
        the sum of its face polygons ...
    :param outline_excess_frac: ... or the outline of the posed cube when that sum exceeds it
        by more than this fraction (a region not the cube's counted; the pose's own error on
        cubes near ``min_area_frac``: within 3-9 %).
    :param min_face_area_frac: smallest area of one face over image area: a face seen edge-on
        is far smaller than the cube it belongs to.
    :param roundness_min: lower roundness bound, eq. 1 (paper: 0.1).
    :param roundness_max: upper roundness bound, eq. 1 (paper: 0.85).
    :param min_solidity: smallest face area over its convex hull area.
    :param sat_min: smallest saturation of a face pixel, 0-1.
    :param val_min: smallest value (brightness) of a face pixel, 0-1.
    :param opening_iterations: iterations of the 3x3 opening (paper: 2).
    :param hough_theta_deg: Hough angular resolution (paper: 2 degrees).
    :param merge_frac: corners of two faces closer than this fraction of the shorter face side
        are one vertex.
    :param min_faces: faces a cube needs (one face alone names no vertex uniquely).
    :param min_support: smallest fraction of each face side backed by an image edge (a streak
        of motion blur across a side scatters its edge points; the shape check guards the
        vertices).
    :param min_step: smallest colour step across a face side (BGR units, 0-255 scale).
    :param work_max_side_px: the mask stage runs on an image at most this big.
    :param strip_max_px: widest face seen edge-on looked for as a strip along a face side
        (``cube_strips``; 0 turns it off).
    :param strip_width_tol_px: a strip's width is a line along its side through the profiles
        that the most of them lie within this many px of, when every other one is wider (a
        box of the strip's colour behind part of it; 0: through all of them).
    :param strip_carry_widen: a strip along a side of a face the border or a post cuts, and
        cut there too, is carried on to the corner the face's completion puts there for the
        shape check when that widens it to at most this many times its widest end seen (0:
        never; ``cube_assembly._completed_strips``).
    :param shape_tol_frac: a vertex farther than this fraction of a face's side from where
        the cube posed on that face puts it is left out (``cube_geometry``).
    :param focal_fracs: focal lengths over the larger image side tried in that check without
        K (the one that explains the most vertices is used).
    :param blur_bands_px: when the sharp pass finds no cube, the faces' sides are looked for
        again as motion-blurred ramps (mid-level crossings), this far either way of the
        rough side, one pass per band, narrowest first, until a cube is found or no face
        ramps wide enough in a band (empty turns it off; a wide band alone misses short ramps
        next to another edge).
    :param split_regions: when no cube is found, cut each colour region that failed the face
        tests or the refinement into faces (``cube_split``: a face joined with a box of its
        own colour) and look again.
    :param split_canny: (low, high) Canny thresholds on the work image of that cut's edges.
    :param split_min_depth_px: smallest depth of a concave corner of a region's outline the
        cut goes along a side from, work-image px.
    :param occluder_reach: a face side is a post's edge (``cube_occluder``: its corners are
        left out) when its edge runs on from this to this fraction of its length past both
        its ends, with the side's outside colour beyond it ...
    :param occluder_min_frac: ... on this fraction of the points read there ...
    :param occluder_max_tilt_deg: ... and it lies within this angle of the image's vertical
        (0: no side is looked at).
    :param occluder_far_reach: when two sides of a face pass, only one whose edge also runs
        on from this to this fraction of its length past both ends is (a post is tall; a cube
        edge runs on only as far as the next face's side in line with it, or a seam); a face
        with none or both such sides is dropped (0, 0: always).
    :param occluder_join_frac: two pieces of one colour, one cut along a post's edge, facing
        each other across it, are one face split by the post (``cube_occluder.join_pieces``)
        when their near corners lie within this fraction of the face's height (2 px at
        least) of the lines through their far corners (0: never joined) ...
    :param occluder_join_aspect: ... and, unless both pieces are cut along the post, the
        joined face is at most this many times as wide as tall (a face seen from beside: not
        two objects of its colour far apart; a top split by the post is wider).
    :param cut_loose_ramp_px: a face the border or a post cuts poses the cube only when its
        seen sides ramp (25-75 %) over at most ``CUT_MAX_RAMP_PX``; when no such pose keeps a
        vertex, one whose sides ramp over at most this many px (a motion streak of about
        twice that) poses it (0: never).
    :param tip_max_frac: a face the border cuts along a side whose side opposite the border is
        at most this fraction of the two sides leaving it is a face with one corner seen,
        rounded by the mask, when its two sides meet there (``cube_tip``; they may ramp over
        ``cut_loose_ramp_px`` at most; 0: never).
    :param fill_min_frac: a face the believed pose shows, of a colour no face found has, is
        reported as the largest region of its colour inside the posed face when that covers
        at least this fraction of it (``cube_fill``; an outline only, no vertex; 0: never).
    :param small_cube_frac: a cube the sharp pass poses whose area is under this fraction of
        the paper's smallest (``min_area_frac``) is the cube in view, too far away, for
        ``cube_track`` to follow (0: never). Under the paper's area at all, the frame's
        retries (split regions, blur) are skipped: they pose the same cube again.
    :param track_full_every: frame after frame (``cube_track``), the whole frame is searched at
        least every this many frames, else only a box around the last frame's cubes (1: every
        frame whole).
    :param track_margin_frac: that box is the cubes' own grown by this fraction of its larger
        side each way ...
    :param track_margin_px: ... and by this many px more (the motion of one frame).
    :param track_max_area_frac: a box larger than this fraction of the frame: the whole frame.
    :param track_lost_wait: when the box shows no cube at all (none posed, of any size or
        place), the whole frame is searched at the next frame instead of this one: the cube
        was lost (hidden, too oblique) far more often than it left the box in one frame.
    :param hold_frames: frame after frame (``cube_track``), a frame where no cube is found
        reports one whole face of a cube detected at most this many frames ago when it is
        that cube's face of its colour moved (from the frame before, when that frame
        reported it so; ``cube_hold``; 0: never): its corners lie
        within ``hold_shape_frac`` of its longest side ...
    :param hold_shape_frac: ... (``hold_shape_px`` at least) of that face's corners mapped by
        the similarity that fits them best ...
    :param hold_shape_px: ... in px; its centre moved at most ``hold_shift_frac`` of its
        longest side ...
    :param hold_shift_frac: ... plus ``hold_shift_px`` per frame since (since the frame
        before, when that frame held it) ...
    :param hold_shift_px: ... px; its area changed by at most ``hold_scale_change`` squared
        either way ...
    :param hold_scale_change: ... (a factor of its size); and only the corners that were
        vertices of that cube, within ``hold_vertex_px`` ...
    :param hold_vertex_px: ... px, are reported, with those vertices' ids.
    :param hold_cut_ramp_px: so is a face cut along one side by a post or the image border,
        when no whole face is, its seen sides ramping (25-75 %) over at most this many px: its
        two seen corners, when that face's other two mapped onto the sides leaving them
        (``cube_hold.held_cut_face``; 0: never).
    """

    hue_red_deg: tuple[float, float] = (340.0, 20.0)
    hue_yellow_deg: tuple[float, float] = (35.0, 75.0)
    hue_purple_deg: tuple[float, float] = (255.0, 325.0)
    sat_min: float = 0.35
    val_min: float = 0.12
    min_area_frac: float = 0.005
    min_face_area_frac: float = 0.0003
    outline_excess_frac: float = 0.1
    roundness_min: float = 0.1
    roundness_max: float = 0.85
    min_solidity: float = 0.9
    opening_iterations: int = 2
    hough_theta_deg: float = 2.0
    merge_frac: float = 0.15
    min_faces: int = 2
    min_support: float = 0.35
    min_step: float = 15.0
    work_max_side_px: int = 640
    strip_max_px: float = 20.0
    strip_width_tol_px: float = 1.5
    strip_carry_widen: float = 2.0
    shape_tol_frac: float = 0.04
    focal_fracs: tuple[float, ...] = (0.5, 0.7, 0.9, 1.2, 1.6)
    blur_bands_px: tuple[float, ...] = (12.0, 24.0)
    split_regions: bool = True
    split_canny: tuple[float, float] = (40.0, 80.0)
    split_min_depth_px: float = 3.0
    occluder_reach: tuple[float, float] = (0.04, 0.2)
    occluder_min_frac: float = 0.6
    occluder_max_tilt_deg: float = 20.0
    occluder_far_reach: tuple[float, float] = (0.2, 0.6)
    occluder_join_frac: float = 0.04
    occluder_join_aspect: float = 1.5
    cut_loose_ramp_px: float = 5.0
    tip_max_frac: float = 0.2
    fill_min_frac: float = 0.5
    small_cube_frac: float = 0.8
    track_full_every: int = 10
    track_margin_frac: float = 0.5
    track_margin_px: float = 40.0
    track_max_area_frac: float = 0.5
    track_lost_wait: bool = True
    hold_frames: int = 8
    hold_shape_frac: float = 0.02
    hold_shape_px: float = 2.0
    hold_shift_frac: float = 0.25
    hold_shift_px: float = 20.0
    hold_scale_change: float = 1.25
    hold_vertex_px: float = 1.5
    hold_cut_ramp_px: float = 5.0

    def __post_init__(self) -> None:
        for name in ('hue_red_deg', 'hue_yellow_deg', 'hue_purple_deg'):
            lo, hi = getattr(self, name)
            if not (0.0 <= lo < 360.0 and 0.0 <= hi <= 360.0):
                raise ValueError(f'{name} must be degrees in [0, 360), got {(lo, hi)}')
        if not 0.0 < self.min_area_frac < 1.0:
            raise ValueError(f'min_area_frac must be in (0, 1), got {self.min_area_frac}')
        if self.outline_excess_frac < 0.0:
            raise ValueError('outline_excess_frac must be >= 0')
        if not 0.0 <= self.roundness_min < self.roundness_max <= 1.0:
            raise ValueError('need 0 <= roundness_min < roundness_max <= 1')
        if not 0.0 <= self.split_canny[0] <= self.split_canny[1]:
            raise ValueError(f'split_canny must be (low, high), 0 <= low <= high, '
                             f'got {self.split_canny}')
        if self.split_min_depth_px <= 0.0:
            raise ValueError(f'split_min_depth_px must be > 0, got {self.split_min_depth_px}')
        if not (0.0 <= self.occluder_reach[0] < self.occluder_reach[1] and
                0.0 < self.occluder_min_frac <= 1.0 and 0.0 <= self.occluder_max_tilt_deg < 90.0):
            raise ValueError('need 0 <= occluder_reach[0] < occluder_reach[1], occluder_min_frac '
                             'in (0, 1] and occluder_max_tilt_deg in [0, 90)')
        if not 0.0 <= self.occluder_far_reach[0] <= self.occluder_far_reach[1]:
            raise ValueError(f'need 0 <= occluder_far_reach[0] <= occluder_far_reach[1], got '
                             f'{self.occluder_far_reach}')
        if self.cut_loose_ramp_px < 0.0 or not 0.0 <= self.tip_max_frac < 1.0:
            raise ValueError('need cut_loose_ramp_px >= 0 and tip_max_frac in [0, 1)')
        if not 0.0 <= self.fill_min_frac <= 1.0:
            raise ValueError(f'fill_min_frac must be in [0, 1], got {self.fill_min_frac}')
        if self.occluder_join_frac < 0.0 or self.occluder_join_aspect <= 0.0:
            raise ValueError('need occluder_join_frac >= 0 and occluder_join_aspect > 0')
        if not 0.0 <= self.small_cube_frac <= 1.0:  # over 1: cubes the paper keeps dropped
            raise ValueError(f'small_cube_frac must be in [0, 1], got {self.small_cube_frac}')
        if self.track_full_every < 1 or self.track_margin_frac < 0.0 or \
                self.track_margin_px < 0.0 or not 0.0 < self.track_max_area_frac <= 1.0:
            raise ValueError('need track_full_every >= 1, track margins >= 0 and '
                             'track_max_area_frac in (0, 1]')
        if self.hold_frames < 0 or min(self.hold_shape_frac, self.hold_shape_px,
                                       self.hold_shift_frac, self.hold_shift_px,
                                       self.hold_vertex_px, self.hold_cut_ramp_px) < 0.0 or \
                self.hold_scale_change < 1.0:
            raise ValueError('need hold_frames >= 0, hold tolerances >= 0 and '
                             'hold_scale_change >= 1')
        if not 1 <= self.min_faces <= 3:
            raise ValueError(f'min_faces must be 1, 2 or 3, got {self.min_faces}')

    def hue_ranges(self) -> dict[str, tuple[float, float]]:
        """Return colour name -> (lo, hi) hue range, degrees."""
        return {'red': self.hue_red_deg, 'yellow': self.hue_yellow_deg,
                'purple': self.hue_purple_deg}


@dataclass(frozen=True, eq=False)
class Face:
    """
    A detected face: colour, (4, 2) corners px, (4, 3) side lines, side supports; ``thin``
    for a strip seen edge-on (``cube_strips``: only its corners 0 and 3 are measured), and
    ``runs_on`` for a strip that is no evidence for a cube pose (its colour goes on past its
    side, it tapers to nothing, or it lies between two faces in the blur retry); ``cut``: the
    side along the image border of a face the border cuts (``_border_side``: that side's line
    is the border's, its two corners are no cube vertices), or along a post's edge in front
    (``cube_occluder``), -1 for none; ``outside``: the
    corner beyond the image border of a face the border cuts across it (``cube_border``: no
    cube vertex, and the face poses nothing), -1 for none; ``seen``: the (4, 2) outlines of
    the pieces a face joined across a post in front shows (``cube_occluder.join_pieces``),
    empty for a face seen whole; ``ramp_px``: how wide the seen sides of a cut face ramp
    (25-75 %, the widest, px; 0 for a face not cut); ``tip``: a face of which the border leaves
    one corner, ``cut + 2`` (``cube_tip``: corner ``cut + 3`` and side line ``cut + 2`` repeat
    it and side ``cut + 3``).
    """

    colour: str
    corners_px: Array
    lines: Array
    supports: Array
    thin: bool = False
    runs_on: bool = False
    cut: int = -1
    outside: int = -1
    seen: tuple[Array, ...] = ()
    ramp_px: float = 0.0
    tip: bool = False


def colour_mask(hsv: npt.NDArray[np.uint8], hue_deg: tuple[float, float], cfg: CubeConfig
                ) -> npt.NDArray[np.uint8]:
    """Return a uint8 0/255 mask of ``hsv`` (OpenCV HSV, H in 0-179) pixels of one colour."""
    lo_h, hi_h = hue_deg[0] / 2.0, hue_deg[1] / 2.0  # OpenCV stores hue / 2
    s_lo, v_lo = int(round(cfg.sat_min * 255)), int(round(cfg.val_min * 255))
    if lo_h <= hi_h:
        return cv2.inRange(hsv, (int(np.ceil(lo_h)), s_lo, v_lo), (int(hi_h), 255, 255))
    a = cv2.inRange(hsv, (int(np.ceil(lo_h)), s_lo, v_lo), (180, 255, 255))
    return a | cv2.inRange(hsv, (0, s_lo, v_lo), (int(hi_h), 255, 255))


def colour_masks(hsv: npt.NDArray[np.uint8], cfg: CubeConfig
                 ) -> dict[str, npt.NDArray[np.uint8]]:
    """
    Return ``colour_mask`` of every cube colour: one saturation-value test and one hue
    look-up table for all of them (a third of the CPU of three ``inRange`` on HSV).
    """
    hue_lut, bit_luts = _colour_luts(tuple(cfg.hue_ranges().items()))
    s_lo, v_lo = int(round(cfg.sat_min * 255)), int(round(cfg.val_min * 255))
    label = cv2.bitwise_and(cv2.LUT(cv2.extractChannel(hsv, 0), hue_lut),
                            cv2.inRange(hsv, (0, s_lo, v_lo), (255, 255, 255)))
    return {c: cv2.LUT(label, lut) for c, lut in bit_luts}


@functools.lru_cache(maxsize=8)
def _colour_luts(hues: tuple[tuple[str, tuple[float, float]], ...]
                 ) -> tuple[npt.NDArray[np.uint8], tuple[tuple[str, npt.NDArray[np.uint8]], ...]]:
    """
    Return the hue look-up table of ``colour_masks`` (bit b for the b-th colour of ``hues``,
    (name, (lo, hi) degrees)) and per colour the table of its bit (0 or 255), made once.
    """
    lut = np.zeros(256, np.uint8)
    for bit, (_, hue) in enumerate(hues):
        lo_h, hi_h = int(np.ceil(hue[0] / 2.0)), int(hue[1] / 2.0)  # OpenCV stores hue / 2
        if lo_h <= hue[1] / 2.0 and hue[0] <= hue[1]:
            lut[lo_h:hi_h + 1] |= 1 << bit
        elif hue[0] > hue[1]:
            lut[lo_h:181] |= 1 << bit
            lut[:hi_h + 1] |= 1 << bit
    values = np.arange(256)
    return lut, tuple((c, np.where(values & (1 << bit), 255, 0).astype(np.uint8))
                      for bit, (c, _) in enumerate(hues))


def _face_quads(mask: npt.NDArray[np.uint8], cfg: CubeConfig, scale: float = 1.0,
                failed: list[npt.NDArray[np.int32]] | None = None,
                min_area: float | None = None,
                borders: tuple[bool, bool, bool, bool] = (False,) * 4
                ) -> tuple[list[tuple[Array, npt.NDArray[np.int32]]], npt.NDArray[np.uint8]]:
    """
    Return (rough quad, contour) of mask components that pass the paper's tests, and the
    opened mask; add to ``failed`` the contours of those big enough that fail the others.
    ``min_area``: smallest face px (default: of a mask the size of the work image);
    ``borders``: (left, top, right, bottom) True where the mask's edge is the image border (a
    five-sided face cut there across a corner is a quad with that corner beyond it).
    """
    kernel = np.ones((3, 3), np.uint8)
    # The paper's opening is on the full image: on a work image ``scale`` times as big, as
    # many 3x3 passes remove as thin a strip (a face seen almost edge-on survives).
    passes = _opening_passes(cfg, scale)
    mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, kernel, iterations=passes)
    if min_area is None:
        min_area = _min_face_area(cfg, mask.shape)
    out: list[tuple[Array, npt.NDArray[np.int32]]] = []
    if cv2.countNonZero(mask) < min_area:
        return out, mask
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    for c in contours:
        passed = _face_test(c, cfg, min_area)
        if passed is None:
            continue
        quad = lines.rough_quad(c) if passed else None
        if quad is None and passed and any(borders):
            quad = cube_border.border_quad(c, mask.shape[1::-1], borders)
        if quad is not None:
            out.append((quad, c))
        elif failed is not None:
            failed.append(c)
    return out, mask


def _opening_passes(cfg: CubeConfig, scale: float) -> int:
    """3x3 opening passes on a work image ``scale`` times the full one."""
    return max(1, int(round(cfg.opening_iterations * scale)))


def _min_face_area(cfg: CubeConfig, shape: tuple[int, ...]) -> float:
    """Smallest face area, px, on an image of ``shape``."""
    return cfg.min_face_area_frac * shape[0] * shape[1]


def _face_test(contour: npt.NDArray[np.int32], cfg: CubeConfig, min_area: float
               ) -> bool | None:
    """
    Return True when a component's outline passes the paper's tests, False when only its
    roundness or convexity fails, None when it is too small.
    """
    area, perim = cv2.contourArea(contour), cv2.arcLength(contour, True)
    # The paper's area is a pixel count: the outline through boundary pixel centres
    # misses about half a pixel all round (perimeter / 2) plus the four corner quarters.
    if area + 0.5 * perim + 1.0 < min_area:
        return None
    roundness = 4.0 * np.pi * area / max(perim, 1e-9) ** 2  # eq. 1 on the outline polygon
    return bool(cfg.roundness_min <= roundness <= cfg.roundness_max and
                area >= cfg.min_solidity * cv2.contourArea(cv2.convexHull(contour)))


def _hough_sides(faces: list[tuple[Array, Array]], cfg: CubeConfig) -> list[Array]:
    """
    Return per face (rough quad, outline px) its (4, 3) side lines, each by a Hough vote over
    the outline near that side (all sides of all faces in one ``lines.hough_lines`` call).
    """
    if not faces:
        return []
    quads = np.stack([q for q, _ in faces])  # (F, 4, 2)
    side_lines = np.stack([lines.side_lines(q) for q in quads])  # (F, 4, 3)
    # Every outline point's distance from each side of its face, and where along it it lies:
    # all faces' outlines at once, (P, 4).
    owner = np.repeat(np.arange(len(faces)), [len(c) for _, c in faces])
    pts = np.concatenate([c for _, c in faces])
    x, y = pts[:, :1], pts[:, 1:]
    ls, quad = side_lines[owner], quads[owner]
    d = np.abs(ls[..., 0] * x + ls[..., 1] * y + ls[..., 2])
    seg = quads[:, NEXT] - quads
    seg_sq = np.maximum((seg * seg).sum(axis=2), 1e-9)[owner]
    seg = seg[owner]
    t = (seg[..., 0] * (x - quad[..., 0]) + seg[..., 1] * (y - quad[..., 1])) / seg_sq
    close = (d < 6.0) & (t > 0.2) & (t < 0.8)  # clear of cut corners
    # A side votes with 5 close points at least; its points in outline order.
    key = owner[:, None] * 4 + np.arange(4)
    counts = np.bincount(key[close], minlength=4 * len(faces))
    voting = counts >= 5
    p, i = np.nonzero(close & voting[key])
    order = np.argsort(key[p, i], kind='stable')
    votes = np.flatnonzero(voting)  # face * 4 + side
    if not len(votes):
        return list(side_lines)
    flat = side_lines.reshape(-1, 3)
    peaks = lines.hough_lines_flat(pts[p[order]], np.searchsorted(votes, key[p, i][order]),
                                   np.arctan2(flat[votes, 1], flat[votes, 0]),
                                   -flat[votes, 2], cfg.hough_theta_deg)
    for v, (theta, rho) in zip(votes, peaks):
        flat[v] = np.array([np.cos(theta), np.sin(theta), -rho])
    return list(side_lines)


def _refine_faces(image_bgr: npt.NDArray[np.uint8], rough: list[tuple[str, Array, Array]],
                  cfg: CubeConfig, blur_band_px: float = 0.0) -> list[Face]:
    """Return the faces of ``rough`` that ``_refine_each`` keeps."""
    return [f for f in _refine_each(image_bgr, rough, cfg, blur_band_px) if f is not None]


def _refine_each(image_bgr: npt.NDArray[np.uint8], rough: list[tuple[str, Array, Array]],
                 cfg: CubeConfig, blur_band_px: float = 0.0, pieces: bool = False
                 ) -> list[Face | None]:
    """
    Refine every face's sides on the full-resolution colour step across each of them; per
    rough face its refined face or None (with ``blur_band_px``: the faces kept only).
    ``pieces`` for faces cut from a region (``_split_faces``): each side's colour step is
    the larger of its two halves' (along the object it was cut from, it has none).

    All sides of all faces go through one ``sides.refine`` call (each on its own colour step:
    red-yellow, red-background... differ), but for faces whose colours an earlier pass
    measured (blur retry, ``pieces``) with a step already under ``min_step``
    (``cube_prune.refine``).

    :param rough: (colour, (4, 3) Hough side lines, (4, 2) rough quad px) per face.
    """
    if not rough:
        return []
    h, w = image_bgr.shape[:2]
    side_lines = np.concatenate([ls for _, ls, _ in rough])
    quads = np.stack([q for _, _, q in rough])  # (F, 4, 2)
    out_corner = cube_border.outside(quads.reshape(-1, 2), w, h).reshape(-1, 4)
    ends = np.stack([quads, quads[:, NEXT]], axis=2).reshape(-1, 2, 2)  # per side its corners
    if out_corner.any():
        ends = cube_border.clip_ends(ends, w, h)
    n = int(np.clip(np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1).max() / 3.0, 12, 48))
    colours = None
    if blur_band_px > 0.0:
        rough, side_lines, ends, colours = _smeared(image_bgr, rough, side_lines, ends, n,
                                                    blur_band_px)
        if not rough:
            return []
    elif pieces:
        colours = _half_colours(image_bgr, side_lines, ends, n)
    reals, cuts, outs = _real_sides(rough, w, h, blur_band_px > 0.0)
    # Where the colours come from an earlier pass, a face with a colour step under
    # ``min_step`` fails whatever its sides refine to: only the others are refined.
    tried, res = cube_prune.refine(image_bgr, side_lines, ends, n, colours, reals, cfg.min_step,
                                   blur_band_px > 0.0)
    if not tried.any():
        return [None] * len(rough)
    refined, supports, steps, inside, outside = res
    # (side lines, supports, corners, border cut) of the faces whose sides pass the checks
    kept: list[tuple[Array, Array, Array, tuple[int, Array] | None] | None] = []
    for f, (colour, hough, quad) in enumerate(rough):
        kept.append(None)  # until it passes
        if not tried[f]:
            continue
        ls, sup = refined[4 * f:4 * f + 4].copy(), supports[4 * f:4 * f + 4].copy()
        out, cut, real = outs[f], cuts[f], reals[f]
        if cut is not None:  # no colour step to find there: the border's own line
            ls[cut[0]] = cut[1]
        if steps[4 * f:4 * f + 4][real].min() < cfg.min_step or \
                sup[real].min() < cfg.min_support:
            continue
        sup[~real] = sup[real].min()
        corners = lines.quad_corners(list(ls))
        hough_corners = lines.quad_corners(list(hough))
        if corners is None or hough_corners is None:
            continue
        if not cv2.isContourConvex(corners.astype(np.float32)):
            continue
        if out >= 0 and not cube_border.outside(corners[out:out + 1], w, h)[0]:
            continue  # the cut sides meet inside the image: not one corner cut off
        # Acute corners are cut by the rough outline, so allow a quarter of the longest side.
        side_px = np.hypot(*(hough_corners - hough_corners[NEXT]).T).max()
        seen = np.arange(4) != out
        if np.abs(corners - hough_corners)[seen].max() > max(4.0, 0.25 * side_px):
            continue  # the refinement ran off to another edge
        kept[-1] = (ls, sup, corners, cut)
    occluded = _occluded(image_bgr, kept, outs, outside, cfg)
    faces: list[Face | None] = []
    for f, (colour, _, _) in enumerate(rough):
        faces.append(None)
        if kept[f] is None:
            continue
        ls, sup, corners, cut = kept[f]  # type: ignore[misc]
        occ = occluded.get(f)
        if occ is not None:
            if occ.sum() > 1:
                continue
            if occ.any():
                cut = (int(np.argmax(occ)), ls[int(np.argmax(occ))])
        real = reals[f]
        # A cut face poses the cube from an extrapolation: only on sharp sides (a motion
        # streak across them shifts its seen corners by pixels); smeared, it is mute.
        ramp = 0.0 if cut is None else float(sides.ramp_widths(
            image_bgr, ls[real], np.stack([corners, corners[NEXT]], 1)[real],
            6.0, inside[4 * f:4 * f + 4][real], outside[4 * f:4 * f + 4][real]).max())
        faces[-1] = Face(colour, corners, ls, sup, runs_on=ramp > CUT_MAX_RAMP_PX,
                         cut=-1 if cut is None else cut[0], outside=outs[f], ramp_px=ramp)
    return faces


def _occluded(image_bgr: npt.NDArray[np.uint8],
              kept: list[tuple[Array, Array, Array, tuple[int, Array] | None] | None],
              outs: list[int], outside: Array, cfg: CubeConfig) -> dict[int, npt.NDArray]:
    """
    Return face index -> (4,) ``cube_occluder.occluder_sides`` of the ``kept`` faces (side
    lines, supports, corners, border cut) that neither the border cuts nor has a corner
    beyond it: a post in front cuts the face along its edge, that side's corners are the
    post's. All faces in one call (one remap).
    """
    at = [f for f, k in enumerate(kept) if k is not None and k[3] is None and outs[f] < 0]
    if not at or cfg.occluder_max_tilt_deg <= 0.0:
        return {}

    def sides_of(faces: list[int], reach: tuple[float, float]) -> npt.NDArray[np.bool_]:
        return cube_occluder.occluder_sides_many(
            image_bgr, np.stack([kept[f][0] for f in faces]),  # type: ignore[index]
            np.stack([kept[f][2] for f in faces]),  # type: ignore[index]
            np.stack([outside[4 * f:4 * f + 4] for f in faces]), cfg.min_step, reach,
            cfg.occluder_min_frac, cfg.occluder_max_tilt_deg)
    found = dict(zip(at, sides_of(at, cfg.occluder_reach)))
    two = [f for f in at if found[f].sum() > 1]
    if two and cfg.occluder_far_reach[1] > 0.0:
        # A cube edge in line with the next face's side (or a seam on the ground) runs on a
        # little way too: the post's edge is the one that runs on far.
        for f, far in zip(two, sides_of(two, cfg.occluder_far_reach)):
            if (far & found[f]).sum() == 1:
                found[f] = far & found[f]
    return found


def _real_sides(rough: list[tuple[str, Array, Array]], w: int, h: int, blurred: bool
                ) -> tuple[npt.NDArray[np.bool_], list[tuple[int, Array] | None], list[int]]:
    """
    Return per rough face (F, 4) True for the sides that must show a colour step (not the
    image border's), the ``_border_side`` cut (None for none; never on ``blurred`` faces or
    faces with a corner beyond the border) and the corner beyond the border (-1 for none).
    """
    real = np.ones((len(rough), 4), bool)
    cuts: list[tuple[int, Array] | None] = []
    outs: list[int] = []
    for f, (_, _, quad) in enumerate(rough):
        away = cube_border.outside(quad, w, h)
        out = int(np.argmax(away)) if away.any() else -1
        cut = None if blurred or out >= 0 else _border_side(quad, w, h)
        if cut is not None:
            real[f, cut[0]] = False
        cuts.append(cut)
        outs.append(out)
    return real, cuts, outs


def _half_colours(image_bgr: npt.NDArray[np.uint8], side_lines: Array, ends: Array, n: int
                  ) -> tuple[Array, Array]:
    """
    Return (S, 3) inside and outside colours of each side, from whichever of its two halves
    shows the larger colour step (``sides.refine``'s first band).
    """
    mid = ends.mean(axis=1)
    halves = np.concatenate([np.stack([ends[:, 0], mid], 1), np.stack([mid, ends[:, 1]], 1)])
    *_, steps, inside, outside = sides.refine(image_bgr, np.concatenate([side_lines] * 2),
                                              halves, (6.0,), max(6, n // 2))
    s = len(side_lines)
    pick = np.where(steps[:s] >= steps[s:], np.arange(s), np.arange(s) + s)
    return inside[pick], outside[pick]


def _border_side(quad: Array, w: int, h: int) -> tuple[int, Array] | None:
    """
    Return (side index, line of the image edge, normal out) when exactly one side of a rough
    face quad (full px) runs along the image border (both ends within ``BORDER_PX``), else
    None: a face the border cuts still shows its other sides and the corners between them.
    """
    near = [(quad[:, 0] <= BORDER_PX, np.array([-1.0, 0.0, -0.5])),
            (quad[:, 0] >= w - 1 - BORDER_PX, np.array([1.0, 0.0, 0.5 - w])),
            (quad[:, 1] <= BORDER_PX, np.array([0.0, -1.0, -0.5])),
            (quad[:, 1] >= h - 1 - BORDER_PX, np.array([0.0, 1.0, 0.5 - h]))]
    found = [(i, line) for at, line in near for i in range(4) if at[i] and at[(i + 1) % 4]]
    return found[0] if len(found) == 1 else None


def _smeared(image_bgr: npt.NDArray[np.uint8], rough: list[tuple[str, Array, Array]],
             side_lines: Array, ends: Array, n: int, band_px: float
             ) -> tuple[list[tuple[str, Array, Array]], Array, Array, tuple[Array, Array]]:
    """
    Return the faces of ``rough`` worth looking for as motion-blurred, with their sides found
    at mid level in a band of ``band_px`` (the first pass of ``sides.refine``), their ends and
    (inside, outside) colours, for the finer passes.

    A face must ramp (25-75 %, about half the streak) over ``BLUR_MIN_RAMP_FRAC`` of the band
    on its most smeared side. In a band wider than ``BLUR_FREE_BAND_PX`` its opposite sides
    must also ramp alike (one streak crosses both): a red building behind the cube passes the
    looser search, but only its side on a grass verge ramps wide. (Not in a band as narrow as
    2x the sharp one: there a side shared with another face, or cut by an occluder, ramps
    unlike its opposite side, and the looser search gains little.)
    """
    first, _, _, inside, outside = sides.refine(image_bgr, side_lines, ends, (band_px,), n,
                                                blurred=True)
    ramps = sides.ramp_widths(image_bgr, first, ends, band_px, inside, outside)
    ramps = ramps.reshape(-1, 2, 2).transpose(0, 2, 1)  # (face, pair, opposite side)
    keep = ramps.max(axis=(1, 2)) >= BLUR_MIN_RAMP_FRAC * band_px
    if band_px > BLUR_FREE_BAND_PX:
        gap = np.abs(ramps[..., 0] - ramps[..., 1])
        keep &= (gap <= np.maximum(2.0, 0.5 * ramps.max(axis=2))).all(axis=1)
    rows = np.repeat(keep, 4)
    return ([r for r, k in zip(rough, keep) if k], first[rows], ends[rows],
            (inside[rows], outside[rows]))


def detect_faces(image_bgr: npt.NDArray[np.uint8], cfg: CubeConfig,
                 half: npt.NDArray[np.uint8] | None = None) -> list[Face]:
    """
    Return every face-like region of each cube colour, refined, full-resolution px.

    :param half: the image box-filtered to half its size (``INTER_AREA``), when another
        detector made it: the work image when that is its size.
    """
    return _refine_faces(image_bgr, rough_faces(image_bgr, cfg, half), cfg)


def rough_faces(image_bgr: npt.NDArray[np.uint8], cfg: CubeConfig,
                half: npt.NDArray[np.uint8] | None = None
                ) -> list[tuple[str, Array, Array]]:
    """
    Return (colour, (4, 3) Hough side lines, (4, 2) rough quad px) of every face-like region
    (the mask stage of ``detect_faces``), full-resolution px.
    """
    return _rough(image_bgr, cfg, half)[0]


def _rough(image_bgr: npt.NDArray[np.uint8], cfg: CubeConfig,
           half: npt.NDArray[np.uint8] | None = None, roi: tuple[int, int, int, int] | None = None
           ) -> tuple[list[tuple[str, Array, Array]], '_Regions']:
    """
    Return ``rough_faces`` and the mask regions behind them, for ``_split_faces``; with
    ``roi`` (x0, y0, x1, y1 full px) the mask stage looks only there.
    """
    h, w = image_bgr.shape[:2]
    scale = min(1.0, cfg.work_max_side_px / max(h, w))
    size = (round(w * scale), round(h * scale))
    box = (0, 0) + size if roi is None else _work_box(roi, scale, size)
    if half is not None and half.shape[1::-1] == size and (w, h) == (2 * size[0], 2 * size[1]):
        work = half[box[1]:box[3], box[0]:box[2]]
    elif roi is not None and (w, h) == (2 * size[0], 2 * size[1]):
        # A 2x2 box filter: the crop's own reduction is the full reduction's crop.
        x0, y0, x1, y1 = box
        work = cv2.resize(image_bgr[2 * y0:2 * y1, 2 * x0:2 * x1], (x1 - x0, y1 - y0),
                          interpolation=cv2.INTER_AREA)
    else:
        work = cv2.resize(image_bgr, size, interpolation=cv2.INTER_AREA)
        work = work[box[1]:box[3], box[0]:box[2]]
    hsv = cv2.cvtColor(work, cv2.COLOR_BGR2HSV)
    origin = np.array(box[:2], np.int32)
    found = []  # (colour, rough quad, outline), full-resolution px
    items: list[tuple[str, npt.NDArray[np.int32], npt.NDArray[np.uint8], int]] = []
    min_area = _min_face_area(cfg, size[::-1])
    borders = (box[0] == 0, box[1] == 0, box[2] == size[0], box[3] == size[1])
    for colour, mask in colour_masks(hsv, cfg).items():
        failed: list[npt.NDArray[np.int32]] = []
        quads, opened = _face_quads(mask, cfg, scale, failed, min_area, borders)
        for quad, contour in quads:
            items.append((colour, contour, opened, len(found)))
            found.append((colour, lines.full_px(quad + origin, scale),
                          _full_px(contour + origin, scale)))
        items.extend((colour, c, opened, -1) for c in failed)
    hough = _hough_sides([(q, c) for _, q, c in found], cfg)
    return ([(c, h, q) for (c, q, _), h in zip(found, hough)],
            _Regions(work, scale, items, origin, _clipped(items, box, size, scale)))


def _clipped(items: list[tuple[str, npt.NDArray[np.int32], npt.NDArray[np.uint8], int]],
             box: tuple[int, int, int, int], size: tuple[int, int], scale: float) -> Array:
    """
    Return (M, 4) full-px boxes (x0, y0, x1, y1) of the regions that reach an edge of the
    work-image ``box`` inside the work image (they may go on past it).
    """
    w, h = box[2] - box[0], box[3] - box[1]
    out = []
    for _, c, _, _ in items:
        x, y, bw, bh = cv2.boundingRect(c)
        if (x == 0 < box[0]) or (y == 0 < box[1]) or (x + bw == w and box[2] < size[0]) or \
                (y + bh == h and box[3] < size[1]):
            out.append(lines.full_px(np.array([x, y, x + bw - 1, y + bh - 1], float)
                                     + np.tile(box[:2], 2), scale))
    return np.array(out).reshape(-1, 4)


def _work_box(roi: tuple[int, int, int, int], scale: float, size: tuple[int, int]
              ) -> tuple[int, int, int, int]:
    """Return a full-px box (x0, y0, x1, y1) as a work-image box, clipped to ``size``."""
    x0, y0 = (max(0, int(np.floor(v * scale))) for v in roi[:2])
    x1, y1 = (min(m, int(np.ceil(v * scale))) for v, m in zip(roi[2:], size))
    return x0, y0, max(x1, x0 + 1), max(y1, y0 + 1)


def _full_px(contour: npt.NDArray[np.int32], scale: float) -> Array:
    """Return a work-image outline (N, 1, 2) as (N, 2) full-resolution px."""
    return lines.full_px(contour.reshape(-1, 2).astype(np.float64), scale)


@dataclass(frozen=True, eq=False)
class _Regions:
    """
    The work image (or the part of it searched), its scale, and per mask region (colour,
    outline px of that part, opened colour mask, index of its rough face or -1 when it failed
    the face tests); ``origin`` (2,) where that part starts in the work image; ``clipped``
    (M, 4) full-px boxes of the regions reaching an edge of that part inside the work image.
    """

    work: npt.NDArray[np.uint8]
    scale: float
    items: list[tuple[str, npt.NDArray[np.int32], npt.NDArray[np.uint8], int]]
    origin: npt.NDArray[np.int32]
    clipped: Array


def _split_faces(image_bgr: npt.NDArray[np.uint8], regions: _Regions,
                 refined: list[Face | None], cfg: CubeConfig) -> list[Face]:
    """
    Return the refined faces of the pieces (``cube_split``) of every region that failed the
    face tests or whose face failed the refinement, and that touches a region of another
    cube colour (a cube shows two faces at least: a red building on its own is left alone).
    """
    passes = _opening_passes(cfg, regions.scale)
    h, w = image_bgr.shape[:2]
    min_area = _min_face_area(cfg, (round(h * regions.scale), round(w * regions.scale)))

    def face_quad(c: npt.NDArray[np.int32]) -> Array | None:
        return lines.rough_quad(c) if _face_test(c, cfg, min_area) else None
    boxes = np.array([cv2.boundingRect(c) for _, c, _, _ in regions.items]).reshape(-1, 4)
    lo, hi = boxes[:, :2] - 2, boxes[:, :2] + boxes[:, 2:] + 2
    near = (lo[:, None] <= hi[None]).all(axis=2) & (lo[None] <= hi[:, None]).all(axis=2)
    colours = np.array([c for c, _, _, _ in regions.items])
    near &= colours[:, None] != colours[None, :]
    found = []
    for r, (colour, contour, mask, f) in enumerate(regions.items):
        if (f >= 0 and refined[f] is not None) or not near[r].any():
            continue
        for piece in cube_split.split(contour, mask, regions.work, face_quad, cfg.split_canny,
                                      cfg.split_min_depth_px, passes):
            piece = piece + regions.origin
            quad = lines.rough_quad(piece)
            found.append((colour, lines.full_px(quad, regions.scale),
                          _full_px(piece, regions.scale)))
    if not found:
        return []
    hough = _hough_sides([(q, c) for _, q, c in found], cfg)
    rough = [(c, h, q) for (c, q, _), h in zip(found, hough)]
    return [f for f in _refine_each(image_bgr, rough, cfg, pieces=True) if f is not None]


def _masks_of(cfg: CubeConfig) -> cube_strips.MaskFn:
    """Return the cube colour test of BGR samples (``cube_strips.MaskFn``)."""
    def masks_of(bgr: npt.NDArray[np.uint8]) -> dict[str, npt.NDArray[np.bool_]]:
        hsv = cv2.cvtColor(bgr, cv2.COLOR_BGR2HSV)
        return {c: m > 0 for c, m in colour_masks(hsv, cfg).items()}
    return masks_of


def _strips(image_bgr: npt.NDArray[np.uint8], faces: list[Face], cfg: CubeConfig
            ) -> list[Face]:
    """Return thin faces (strips of another cube colour) along unshared face sides."""
    if cfg.strip_max_px <= 0.0:
        return []
    out = []
    for colour, corners, support, runs_on in cube_strips.strip_faces(
            image_bgr, [f.corners_px for f in faces], [f.colour for f in faces],
            _masks_of(cfg), cfg.strip_max_px, width_tol=cfg.strip_width_tol_px):
        out.append(Face(colour, corners, lines.side_lines(corners), np.full(4, support),
                        thin=True, runs_on=runs_on))
    return out


def detect_cubes(image_bgr: npt.NDArray[np.uint8], cfg: CubeConfig,
                 K: Array | None = None, half: npt.NDArray[np.uint8] | None = None,
                 roi: tuple[int, int, int, int] | None = None,
                 small: list[targets.TargetDetection] | None = None,
                 posed: list[targets.TargetDetection] | None = None,
                 faces_out: list[Face] | None = None) -> list[targets.TargetDetection]:
    """
    Find tri-colour cubes in a BGR image.

    :param image_bgr: (H, W, 3) uint8 BGR image.
    :param K: (3, 3) intrinsics px for the cube shape check, or None to estimate.
    :param half: the image box-filtered to half its size, when another detector made it.
    :param roi: (x0, y0, x1, y1) full px: look only there, and find nothing when a cube comes
        within ``track_margin_px / 2`` of the box's edge inside the image, or a colour region
        reaching that edge within ``strip_max_px`` of a cube (either may go on past it):
        ``cube_track`` then searches the whole frame.
    :param small: when nothing is found but cubes too small (``small_cube_frac``), they are
        added here (for ``cube_track``: the cube in view, too far away).
    :param posed: every cube posed is added here, whether returned or not (under the paper's
        area, or too near the edge of ``roi``).
    :param faces_out: the faces the sharp pass refined are added here (for ``cube_hold``).
    :returns: one detection per cube, with vertices, ids (see ``targets``), edges and
        per-face polygons.
    """
    rough, regions = _rough(image_bgr, cfg, half, roi)
    Ks = [K] if K is not None else [cube_geometry.default_K(image_bgr.shape, f)
                                    for f in cfg.focal_fracs]
    refined = _refine_each(image_bgr, rough, cfg)
    if cfg.tip_max_frac > 0.0:
        for f, tip in cube_tip.tip_faces(image_bgr, rough, refined, _border_side, Face,
                                         cfg.tip_max_frac, cfg.min_step, cfg.min_support,
                                         cfg.cut_loose_ramp_px):
            refined[f] = tip
    faces = [f for f in refined if f is not None]
    if faces_out is not None:
        faces_out += faces
    under: list[tuple[targets.TargetDetection, float]] = []
    out = _cubes(image_bgr, list(faces), cfg, Ks, small=under)
    if posed is not None:
        posed += [d for d, _ in under]
    if under and not out:
        # The cube in view is posed, but under the paper's area: the retries would find it
        # again. Far under it, it is the one for ``cube_track`` to follow.
        tiny = [d for d, a in under if a < cfg.small_cube_frac]
        if tiny and small is not None and (roi is None or all(
                _inside(d, roi, regions.clipped, image_bgr.shape, cfg) for d in tiny)):
            small += tiny
        return []
    if not out and cfg.split_regions:
        # A face joined with an object of its own colour: cut such regions into faces.
        split = _split_faces(image_bgr, regions, refined, cfg)
        if split:
            out = _cubes(image_bgr, faces + split, cfg, Ks)
    for band in sorted(cfg.blur_bands_px) if rough else ():
        if out:
            break
        # Motion blur smears a face's sides into ramps: the steepest point wanders along
        # them, and the mask stops short of a side shared with another face. Where nothing
        # is found, look again for the sides at the mid level of wider ramps.
        kept = _refine_each(image_bgr, rough, cfg, band)
        if not kept:
            # No face ramps over BLUR_MIN_RAMP_FRAC of this band, as a smeared cube would (a
            # 14-35 px streak ramps 7-17 px): a wider band only reaches other edges farther off.
            break
        out = _cubes(image_bgr, [f for f in kept if f is not None], cfg, Ks, True)
    if posed is not None:
        posed += out
    if roi is not None and not all(_inside(d, roi, regions.clipped, image_bgr.shape, cfg)
                                   for d in out):
        return []
    return out


def extent(dets: list[targets.TargetDetection]) -> tuple[Array, Array]:
    """Return the (2,) lowest and highest px of the cubes' face polygons and vertices."""
    pts = np.concatenate([p for d in dets for _, p in d.polygons] + [d.vertices_px for d in dets])
    return pts.min(axis=0), pts.max(axis=0)


def _inside(det: targets.TargetDetection, roi: tuple[int, int, int, int], clipped: Array,
            shape: tuple[int, ...], cfg: CubeConfig) -> bool:
    """Return True when a cube found in ``roi`` is clear of its edges (``detect_cubes``)."""
    lo, hi = extent([det])
    m = 0.5 * cfg.track_margin_px
    h, w = shape[:2]
    if (roi[0] > 0 and lo[0] < roi[0] + m) or (roi[1] > 0 and lo[1] < roi[1] + m) or \
            (roi[2] < w and hi[0] > roi[2] - 1 - m) or (roi[3] < h and hi[1] > roi[3] - 1 - m):
        return False
    g = cfg.strip_max_px
    return not ((clipped[:, :2] <= hi + g).all(axis=1) &
                (clipped[:, 2:] >= lo - g).all(axis=1)).any()


def _cubes(image_bgr: npt.NDArray[np.uint8], faces: list[Face], cfg: CubeConfig,
           Ks: list[Array], blurred: bool = False,
           small: list[tuple[targets.TargetDetection, float]] | None = None
           ) -> list[targets.TargetDetection]:
    """
    Return the cubes that ``faces`` (refined, not yet with strips) assemble into;
    ``blurred`` for faces of the blur retry. Add to ``small`` (cube, area over the paper's)
    of the cubes they pose under the paper's area (without ``small``: not posed at all).
    """
    if not faces:
        return []
    if cfg.occluder_join_frac > 0.0:
        faces = cube_occluder.join_pieces(faces, cfg.occluder_join_frac,
                                          cfg.occluder_join_aspect)
    faces += _strips(image_bgr, faces, cfg)
    labels = cube_assembly.cluster_corners(faces, cfg.merge_frac)
    if blurred:
        # Looser sides let a box behind the cube pose it from a strip that is the cube's own
        # face seen edge-on between the two: no such evidence here.
        faces = cube_assembly.mute_sandwiched(faces, labels)
    # Faces that share two vertices share an edge: union them into cubes.
    parent = list(range(len(faces)))
    for a in range(len(faces)):
        for b in range(a + 1, len(faces)):
            shared = set(labels[4 * a:4 * a + 4]) & set(labels[4 * b:4 * b + 4])
            if len(shared) >= 2:
                parent[cube_assembly.find(parent, a)] = cube_assembly.find(parent, b)
    groups: dict[int, list[int]] = {}
    for f in range(len(faces)):
        groups.setdefault(cube_assembly.find(parent, f), []).append(f)
    out = []
    for members in groups.values():
        thick = [f for f in members if not faces[f].thin]
        colours = {faces[f].colour for f in thick}
        if len(colours) < len(thick):
            continue  # opposite faces are never both visible: same colour twice is not a cube
        # One face seen edge-on along two faces gives two strips; none is a face found whole.
        members = thick + [f for f in members if faces[f].thin and faces[f].colour not in colours]
        if len(colours | {faces[f].colour for f in members}) < cfg.min_faces:
            continue
        area = sum(cv2.contourArea(faces[f].corners_px.astype(np.float32)) for f in members)
        min_area = cfg.min_area_frac * image_bgr.shape[0] * image_bgr.shape[1]
        if area < min_area and small is None:
            continue  # the paper's area test, on the whole cube
        outline: list[float | None] = []
        det = cube_assembly.cube_detection(
            [faces[f] for f in members], [labels[4 * f:4 * f + 4] for f in members],
            Ks, image_bgr.shape, cfg.shape_tol_frac, cfg.cut_loose_ramp_px,
            cfg.strip_carry_widen, outline,
            lambda colour, outlines: cube_strips.best_outline(image_bgr, colour, outlines,
                                                              _masks_of(cfg)),
            None if cfg.fill_min_frac <= 0.0 else
            lambda colour, face: cube_fill.colour_outline(image_bgr, colour, face,
                                                          _masks_of(cfg), cfg.fill_min_frac))
        if det is None:
            continue
        if outline[0] is not None and area > (1.0 + cfg.outline_excess_frac) * outline[0]:
            # A box of a face's colour behind the cube, joined with that face or taken for
            # one seen edge-on, adds to the faces' sum but not to the posed cube's outline.
            area = outline[0]
        if area < min_area:
            if small is not None:
                small.append((det, area / min_area))
        else:
            out.append(det)
    out.sort(key=lambda d: -d.score)
    return out
