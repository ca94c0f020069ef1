"""
Sheet-of-paper detection: a bright, unsaturated quadrilateral on a darker surface.

The paper's indoor variant of Step 1. Candidates come from whiteness masks (the smallest of the
B, G, R channels is high only on white, unsaturated surfaces) at a few thresholds on a
downscaled image, filtered like the cube faces (area >= 0.005 of the image, roundness eq. 1
in [0.1, 0.85], area close to the convex hull), and simplified to four corners. Each side is
then refined on the full-resolution image: edge points where the whiteness drops across the
side (sub-pixel, on intensity profiles), a robust line fit, corners as intersections of the
refined lines. A candidate is kept when every side is backed by image gradient and the
rectangle it implies has the configured aspect ratio.
"""
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core import lines, quads, sides, targets

Array = npt.NDArray[np.float64]


@dataclass(frozen=True)
class SheetConfig:
    """
    Thresholds of the sheet detector; defaults are the paper's values where it gives one.

    :param sheet: 'letter', 'a4' or 'custom' (then ``size_m`` is used).
    :param size_m: (short, long) side of a custom sheet, m.
    :param min_area_frac: smallest sheet area over image area (paper: 0.005).
    :param roundness_min: lower roundness bound, eq. 1 (paper: 0.1).
    :param roundness_max: upper roundness bound, eq. 1 (paper: 0.85).
    :param min_solidity: smallest region area over its convex hull area (convexity test).
    :param aspect_tol: largest relative deviation of the recovered long/short side ratio.
    :param min_support: smallest fraction of each side backed by an image edge.
    :param min_contrast: smallest BGR colour step across every side (0-255).
    :param work_max_side_px: the candidate search runs on an image at most this big.
    :param canny_low: lower Canny threshold of the colour-edge candidates (BGR, 0-255).
    :param canny_high: upper Canny threshold of the colour-edge candidates.
    :param focal_frac: focal length over the larger image side, used for the aspect check
        when no camera model is given and the quadrilateral does not determine it.
    :param line_candidates: when the masks give no sheet, also try quadrilaterals of straight
        edges scored by gradient support (``quads``): a page on other pages or on a desk of
        the same white. Off for video: in a textured room it costs tens of ms on every frame
        without a sheet; ``absscale detect`` (still images) turns it on.
    :param line_work_max_side_px: the line search runs on an image at most this big.
    :param line_max_refine: line hypotheses refined at full resolution, best supported first.
    :param max_inside_spread: largest distance of the colour just inside one side from the
        median over the four sides, over the brightest channel of that median (one sheet).
    :param max_saturation: largest (max - min) / max channel of that median colour (paper is
        unsaturated; a shaded sheet or a warm light stays well below this).
    :param max_outside_spread: the same spread test just outside the sides (the surface the
        sheet lies on), looser: shadows and a second surface at one side are common.
    """

    sheet: str = 'letter'
    size_m: tuple[float, float] = (0.0, 0.0)
    min_area_frac: float = 0.005
    roundness_min: float = 0.1
    roundness_max: float = 0.85
    min_solidity: float = 0.85
    aspect_tol: float = 0.15
    min_support: float = 0.5
    min_contrast: float = 10.0
    work_max_side_px: int = 480
    focal_frac: float = 0.9
    canny_low: int = 20
    canny_high: int = 50
    line_candidates: bool = False
    line_work_max_side_px: int = 320
    line_max_refine: int = 3
    max_inside_spread: float = 0.25
    max_saturation: float = 0.35
    max_outside_spread: float = 0.5

    def __post_init__(self) -> None:
        if not 0.0 < self.min_area_frac < 1.0:
            raise ValueError(f'min_area_frac must be in (0, 1), got {self.min_area_frac}')
        if not 0.0 <= self.roundness_min < self.roundness_max <= 1.0:
            raise ValueError('need 0 <= roundness_min < roundness_max <= 1')
        if self.work_max_side_px < 64:
            raise ValueError(f'work_max_side_px too small: {self.work_max_side_px}')
        self.model()  # raises ValueError on an unknown sheet

    def model(self) -> targets.SheetModel:
        """Return the configured sheet model."""
        size = self.size_m if self.sheet == 'custom' else None
        return targets.sheet_model(self.sheet, size)


def whiteness(image_bgr: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]:
    """Return the (H, W) uint8 per-pixel minimum over B, G, R: high only on white."""
    b, g, r = cv2.split(image_bgr)
    return cv2.min(cv2.min(b, g), r)


def rectangle_aspect(corners_px: Array, K: Array | None, focal_px: float,
                     centre_px: Array) -> float:
    """
    Return the long/short side ratio of the rectangle whose image is ``corners_px`` (4, 2).

    Zhang and He's whiteboard method: the two vanishing points give the focal length when it
    is unknown (``K`` None), which falls back to ``focal_px`` when the sides are too close to
    parallel to tell; with the intrinsics the homography gives the side ratio.
    """
    m = np.hstack([corners_px[[0, 1, 3, 2]], np.ones((4, 1))])  # m1 (0,0) m2 (w,0) m3 (0,h)
    k2 = np.cross(m[0], m[3]) @ m[2] / (np.cross(m[1], m[3]) @ m[2])
    k3 = np.cross(m[0], m[3]) @ m[1] / (np.cross(m[2], m[3]) @ m[1])
    n2, n3 = k2 * m[1] - m[0], k3 * m[2] - m[0]
    if K is None:
        u0, v0 = centre_px
        f2 = focal_px ** 2
        if abs(n2[2] * n3[2]) > 1e-12:
            est = -((n2[0] * n3[0] - (n2[0] * n3[2] + n2[2] * n3[0]) * u0
                     + n2[2] * n3[2] * u0 ** 2)
                    + (n2[1] * n3[1] - (n2[1] * n3[2] + n2[2] * n3[1]) * v0
                       + n2[2] * n3[2] * v0 ** 2)) / (n2[2] * n3[2])
            if (0.3 * focal_px) ** 2 < est < (3.0 * focal_px) ** 2:
                f2 = est
        K = np.array([[np.sqrt(f2), 0.0, u0], [0.0, np.sqrt(f2), v0], [0.0, 0.0, 1.0]])
    Ki = np.linalg.inv(K)
    a2, a3 = Ki @ n2, Ki @ n3
    ratio = float(np.sqrt((a2 @ a2) / max(a3 @ a3, 1e-18)))
    return max(ratio, 1.0 / max(ratio, 1e-12))


def _masks(work_bgr: npt.NDArray[np.uint8], work_white: npt.NDArray[np.uint8],
           cfg: SheetConfig) -> list[npt.NDArray[np.uint8]]:
    """
    Return binary candidate masks on the work image.

    Whiteness above a few thresholds (Otsu and two higher levels) finds a sheet that is
    clearly brighter than its surface; regions enclosed by colour edges (Canny on BGR) find
    one that differs from the surface mostly in tint, where no grey threshold separates them.
    """
    otsu, _ = cv2.threshold(work_white, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    hist = np.cumsum(np.bincount(work_white.ravel(), minlength=256))
    top = float(np.searchsorted(hist, 0.995 * hist[-1]))  # 99.5th percentile
    masks = [(work_white > t).astype(np.uint8)
             for t in (otsu, otsu + (top - otsu) / 3.0, otsu + 2.0 * (top - otsu) / 3.0)]
    blurred = cv2.GaussianBlur(work_bgr, (3, 3), 0)
    edges = cv2.Canny(blurred, cfg.canny_low, cfg.canny_high)
    edges = cv2.dilate(edges, np.ones((3, 3), np.uint8))
    free = (edges == 0).astype(np.uint8)
    masks.append(free)  # edge-free regions: a sheet's blank areas
    # Everything the image border cannot reach without crossing an edge: objects on the
    # surface, with their text and drawings filled in.
    flood = np.pad(free, 1, constant_values=1)
    cv2.floodFill(flood, None, (0, 0), 2)
    masks.append((flood[1:-1, 1:-1] != 2).astype(np.uint8))
    return masks


def _candidates(work_bgr: npt.NDArray[np.uint8], work_white: npt.NDArray[np.uint8],
                cfg: SheetConfig) -> list[Array]:
    """Return rough (4, 2) quadrilaterals, work-image px, from the candidate masks."""
    min_area = cfg.min_area_frac * work_white.shape[0] * work_white.shape[1]
    kernel = np.ones((3, 3), np.uint8)
    quads: list[Array] = []
    for mask in _masks(work_bgr, work_white, cfg):
        # Closing heals thin dark lines across the sheet (text, a cable); the paper's 3x3
        # opening, twice, then drops thin bridges to neighbouring objects.
        mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
        mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, kernel, iterations=2)
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        for c in contours:
            quad = _shape_ok(c, min_area, cfg)
            if quad is None or _touches_border(quad, work_white.shape):
                continue  # a sheet cut by the image border has no trustworthy corners
            if all(np.abs(quad - q).max() > 2.0 for q in quads):
                quads.append(quad)
    return quads


def _touches_border(quad: Array, shape: tuple[int, ...]) -> bool:
    """Return True when a work-image quad reaches within 1.5 px of the image border."""
    h, w = shape[:2]
    return bool((quad.min() < 1.5) or (quad[:, 0].max() > w - 2.5) or (quad[:, 1].max() > h - 2.5))


def _shape_ok(contour: npt.NDArray[np.int32], min_area: float,
              cfg: SheetConfig) -> Array | None:
    """Apply the area, roundness (eq. 1) and convexity tests; return the rough quad or None."""
    area = cv2.contourArea(contour)
    if area < min_area:
        return None
    roundness = 4.0 * np.pi * area / max(cv2.arcLength(contour, True), 1e-9) ** 2  # eq. 1
    if not cfg.roundness_min <= roundness <= cfg.roundness_max:
        return None
    if area < cfg.min_solidity * cv2.contourArea(cv2.convexHull(contour)):
        return None
    return lines.rough_quad(contour)


def _order(corners: Array) -> Array:
    """Return corners clockwise on screen (y down) from the one with the smallest u + v."""
    centre = corners.mean(axis=0)
    ang = np.arctan2(corners[:, 1] - centre[1], corners[:, 0] - centre[0])
    corners = corners[np.argsort(ang)]  # increasing angle is clockwise when y points down
    return np.roll(corners, -int(np.argmin(corners.sum(axis=1))), axis=0)


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
    centre = quad_px.mean(axis=0)
    ends = np.stack([quad_px, np.roll(quad_px, -1, axis=0)], axis=1)
    rough = np.array([lines.line_through(p0, p1, centre) for p0, p1 in ends])
    n = int(np.clip(np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1).mean() / 4.0, 16, 64))
    refined, supports, steps, inside, outside = sides.refine(
        image_bgr, rough, ends, (coarse_band_px, 4.0, 3.0), n)
    corners = lines.quad_corners(list(refined))
    if corners is None or not cv2.isContourConvex(corners.astype(np.float32)):
        return None
    if np.abs(corners - quad_px).max() > 2.0 * coarse_band_px + 4.0:
        return None
    return corners, supports, steps, inside, outside


def detect_sheets(image_bgr: npt.NDArray[np.uint8], cfg: SheetConfig,
                  K: Array | None = None) -> list[targets.TargetDetection]:
    """
    Find every sheet of the configured size in a BGR image.

    Candidates come from the region masks first; only when none passes are quadrilaterals of
    straight edges tried (``quads``), which costs a few more milliseconds.

    :param image_bgr: (H, W, 3) uint8 BGR image.
    :param K: (3, 3) intrinsics px for the aspect check, or None to estimate.
    :returns: detections, best first; each has 4 corners ordered as in ``targets``.
    """
    h, w = image_bgr.shape[:2]
    scale = min(1.0, cfg.work_max_side_px / max(h, w))
    work = cv2.resize(image_bgr, (round(w * scale), round(h * scale)),
                      interpolation=cv2.INTER_AREA)
    found: list[tuple[float, Array]] = []
    for quad in _candidates(work, whiteness(work), cfg):
        _accept(image_bgr, (quad + 0.5) / scale - 0.5, max(6.0, 3.0 / scale), cfg, K, found)
    if not found and cfg.line_candidates:
        for quad_full, band in _line_candidates(image_bgr, cfg):
            _accept(image_bgr, quad_full, band, cfg, K, found)
    found.sort(key=lambda sc: -sc[0])
    return [_detection(c, s, cfg.model()) for s, c in found]


def _line_candidates(image_bgr: npt.NDArray[np.uint8], cfg: SheetConfig
                     ) -> list[tuple[Array, float]]:
    """Return (full-resolution quad, refinement band px) hypotheses from straight edges."""
    h, w = image_bgr.shape[:2]
    scale = min(1.0, cfg.line_work_max_side_px / max(h, w))
    work = cv2.resize(image_bgr, (round(w * scale), round(h * scale)),
                      interpolation=cv2.INTER_AREA)
    min_side = np.sqrt(cfg.min_area_frac * work.shape[0] * work.shape[1] / cfg.model().aspect)
    hyps, _ = quads.find_quads(work, quads.QuadConfig(min_side_px=float(min_side)))
    centre = np.array([(work.shape[1] - 1) / 2.0, (work.shape[0] - 1) / 2.0])
    kept: list[Array] = []
    for quad in hyps:  # best supported first
        aspect = rectangle_aspect(quad, None, cfg.focal_frac * max(work.shape), centre)
        if abs(aspect / cfg.model().aspect - 1.0) > 2.0 * cfg.aspect_tol:
            continue  # rough corners: a looser test here, the exact one after refinement
        if all(np.abs(quad - q).max() > 2.0 for q in kept):  # neighbouring Hough peaks
            kept.append(quad)
        if len(kept) == cfg.line_max_refine:
            break
    return [((q + 0.5) / scale - 0.5, max(6.0, 3.0 / scale)) for q in kept]


def _accept(image_bgr: npt.NDArray[np.uint8], quad_full: Array, band: float, cfg: SheetConfig,
            K: Array | None, found: list[tuple[float, Array]]) -> None:
    """Refine a candidate; append (score, corners) to ``found`` when it passes every test."""
    h, w = image_bgr.shape[:2]
    if any(np.hypot(*(quad_full[:, None] - c[None]).T).min(axis=0).max() <= band
           for _, c in found):
        return  # another mask's outline of a sheet already found
    refined = refine_quad(image_bgr, quad_full, band)
    if refined is None or refined[1].min() < cfg.min_support:
        return
    if refined[2].min() < cfg.min_contrast:
        return  # not a sheet on a different surface all round
    if not _one_colour(refined[3], cfg.max_inside_spread, cfg.max_saturation):
        return  # four edges of different things (a table top, its legs, the floor)
    if not _one_colour(refined[4], cfg.max_outside_spread, 1.0):
        return  # a sheet lies on one surface: wall between table legs, floor below
    corners = refined[0]
    aspect = rectangle_aspect(corners, K, cfg.focal_frac * max(h, w),
                              np.array([(w - 1) / 2.0, (h - 1) / 2.0]))
    if abs(aspect / cfg.model().aspect - 1.0) > cfg.aspect_tol:
        return
    if all(np.abs(corners - c).max() > 4.0 for _, c in found):
        found.append((float(refined[1].mean()), corners))


def _one_colour(bgr: Array, max_spread: float, max_saturation: float) -> bool:
    """Return True when (4, 3) side colours are one colour, no more saturated than given."""
    ref = np.median(bgr, axis=0)
    level = max(float(ref.max()), 1.0)
    spread = float(np.linalg.norm(bgr - ref, axis=1).max())
    return spread <= max_spread * level and \
        float(ref.max() - ref.min()) <= max_saturation * level


def _detection(corners: Array, score: float, model: targets.SheetModel
               ) -> targets.TargetDetection:
    corners = _order(corners)
    return targets.TargetDetection(
        target_type='sheet', name=model.name, vertices_px=corners,
        vertex_ids=np.arange(4, dtype=np.int64), edges=model.edges(),
        polygons=(('sheet', corners),), score=score)
