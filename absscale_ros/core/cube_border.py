"""
Cube faces with one corner beyond the image border.

The border cutting a face across one corner leaves a five-sided region: three corners and two
whole sides seen, and the two sides at the outside corner seen up to the border (as a sheet
in ``sheet_border``). Such a face is its four sides: the outside corner is where its two cut
sides meet, beyond the border. It is no cube vertex and poses nothing (an extrapolation), but
the face's colour names the corners it shares and its outline confirms a pose posed on
another face; a top face cut so at the side of the frame is the commonest case. The same
outline simplification also gives the quad of a face cut along a side whose acute corner the
mask rounds (``lines.rough_quad`` finds no four corners there).
"""
import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core import lines

Array = npt.NDArray[np.float64]


def border_quad(contour: npt.NDArray[np.int32], size: tuple[int, int],
                borders: tuple[bool, bool, bool, bool], tol_px: float = 1.5,
                frac: float = 0.01, merge_frac: float = 0.03) -> Array | None:
    """
    Return the (4, 2) quad, work px, of a region on a work image of ``size`` (w, h) that the
    image border cuts, or None. Its convex outline is simplified (``frac`` of its perimeter)
    and corners closer than ``merge_frac`` of it merged (an acute corner rounded by the mask
    opening gives two), leaving one side along a border (both ends within ``tol_px`` of it):
    four corners are a face cut along a side (two on the border, ``_border_side``), five a
    face cut across a corner, which becomes a quad with that corner (where the two sides
    leaving the border meet) beyond the border.

    :param borders: (left, top, right, bottom) True where that edge of the work image is the
        image's border (a crop's inner edges are not).
    """
    hull = cv2.convexHull(contour)
    perim = cv2.arcLength(hull, True)
    poly = cv2.approxPolyDP(hull, frac * perim, True).reshape(-1, 2).astype(np.float64)
    gap = np.hypot(*(poly - np.roll(poly, -1, axis=0)).T)
    while len(poly) > 4 and gap.min() < merge_frac * perim:
        i = int(np.argmin(gap))
        poly = np.delete(poly, (i + 1) % len(poly), axis=0)  # the first of the two stays
        gap = np.hypot(*(poly - np.roll(poly, -1, axis=0)).T)
    if len(poly) not in (4, 5):
        return None
    w, h = size
    gaps = np.stack([poly[:, 0], poly[:, 1], w - 1 - poly[:, 0], h - 1 - poly[:, 1]], axis=1)
    on = (gaps <= tol_px) & np.array(borders)[None, :]  # corner on that border
    both = on & np.roll(on, -1, axis=0)  # side i (corners i, i + 1) along that border
    sides = np.flatnonzero(both.any(axis=1))
    if len(sides) != 1 or on.any(axis=1).sum() != 2:
        return None  # another corner on a border too: cut twice, or at a frame corner
    if len(poly) == 4:
        return poly
    i = int(sides[0])
    p = np.roll(poly, -i, axis=0)  # p0 p1 along the border, p2 p3 p4 seen corners
    centre = p[2:].mean(axis=0)
    far = lines.intersect(lines.line_through(p[4], p[0], centre),
                          lines.line_through(p[1], p[2], centre))
    k = int(np.argmax(both[i]))
    if far is None or (-far[0], -far[1], far[0] - (w - 1), far[1] - (h - 1))[k] <= 0.0:
        return None  # the two sides meet inside: no face corner beyond the border
    return np.array([far, p[2], p[3], p[4]])


def outside(points_px: Array, w: int, h: int) -> npt.NDArray[np.bool_]:
    """Return (N,) True for points (N, 2) px beyond the border of a ``w`` x ``h`` image."""
    return (lines.border_gaps(points_px, w, h) < 0.0).any(axis=1)


def clip_ends(ends: Array, w: int, h: int) -> Array:
    """
    Return side ends (S, 2, 2) px with an end beyond the image border moved along its side
    onto the border (a side the border cuts is refined on its seen part only).
    """
    out = ends.copy()
    lo, hi = np.array([0.0, 0.0]), np.array([w - 1.0, h - 1.0])
    for s, e in np.argwhere(outside(ends.reshape(-1, 2), w, h).reshape(-1, 2)):
        a, b = ends[s, e], ends[s, 1 - e]  # b is the seen end
        d = a - b
        with np.errstate(divide='ignore'):
            t = np.min(np.where(d > 0, (hi - b) / d, np.where(d < 0, (lo - b) / d, np.inf)))
        out[s, e] = b + min(1.0, float(t)) * d
    return out
