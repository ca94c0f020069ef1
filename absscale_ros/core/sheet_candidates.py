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


def shrink(image: npt.NDArray[np.uint8], scale: float) -> npt.NDArray[np.uint8]:
    """
    Return ``image`` resized by ``scale`` (<= 1): box-filtered halvings (OpenCV's fast
    integer-factor path), then bilinear to the exact size; about 6x less CPU than one
    ``INTER_AREA`` resize by a non-integer factor, and as free of aliasing.
    """
    h, w = image.shape[:2]
    size = (round(w * scale), round(h * scale))
    out = image
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


def candidates(work_bgr: npt.NDArray[np.uint8], cfg: 'SheetConfig'
               ) -> tuple[list[Array], list[Array]]:
    """
    Return rough (4, 2) quadrilaterals and (5, 2) pentagons (a sheet with a corner hidden),
    work-image px, from the candidate masks.
    """
    work_white = whiteness(work_bgr)
    min_area = cfg.min_area_frac * work_white.shape[0] * work_white.shape[1]
    kernel = np.ones((3, 3), np.uint8)
    quads: list[Array] = []
    pents: list[Array] = []
    for mask in masks(work_bgr, work_white, cfg):
        # Closing heals thin dark lines across the sheet (text, a cable); the paper's 3x3
        # opening, twice, then drops thin bridges to neighbouring objects.
        mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
        mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, kernel, iterations=2)
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        for c in contours:
            if cfg.min_seen < 1.0 and cv2.contourArea(c) >= min_area:
                pent = sheet_partial.pentagon(c)  # a corner cut off: tried if nothing else is
                if pent is not None and all(np.abs(pent - q).max() > 2.0 for q in pents):
                    pents.append(pent)
            quad = shape_ok(c, min_area, cfg)
            if quad is None or touches_border(quad, work_white.shape):
                continue  # a sheet cut by the image border has no trustworthy corners
            if all(np.abs(quad - q).max() > 2.0 for q in quads):
                quads.append(quad)
    return quads, pents


def touches_border(quad: Array, shape: tuple[int, ...], margin: float = 1.5) -> bool:
    """Return True when a polygon reaches within ``margin`` px of the image border."""
    h, w = shape[:2]
    return bool((quad.min() < margin) or (quad[:, 0].max() > w - 1 - margin)
                or (quad[:, 1].max() > h - 1 - margin))


def shape_ok(contour: npt.NDArray[np.int32], min_area: float,
             cfg: 'SheetConfig') -> Array | None:
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
