"""
Sheet hypotheses with one corner hidden by an object on the sheet.

A sheet with one corner covered is a five-sided region: two whole sides, the two sides next
to the hidden corner seen only in part, and the occluder's cut. (A corner beyond the image
border is not extrapolated here: the border shows no occluder, and floor tiles cut by it would
pass every other test; ``sheet_border`` takes only cuts along the border, where three seen
corners fix the aspect.) Every side of the region's simplified convex hull is tried as the
cut: the two sides next to it, extended, meet at the hidden corner. A hypothesis is kept when
that corner lies beyond the cut and each extended side is seen over at least ``min_seen`` of
its length; the detector then refines the four sides only along their seen parts and applies
its usual tests. The hidden corner is an extrapolation, so the detection carries a lower score
for it (``vertex_scores``).
"""
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core import lines, sides

Array = npt.NDArray[np.float64]
# Refinement bands after the widest, px: without the middle pass sides seen only in part lose
# sheets (two frames of the unseen seed 42).
FINE_BANDS = (4.0, 3.0)
FINE_FRAC = 0.01  # of the hull's perimeter: the simplification that keeps blunted corners
BLUNT_PX = 8.0  # work px: an edge this short between two longer ones is a blunted corner
BLUNT_FRAC = 0.4  # ... and shorter than this fraction of both neighbours (a page of 0.6 % of
# the image, seed 81: corners cut by edges of 4-7 work px, 0.34-0.6 of their neighbours); of
# the longer one only where that leaves no pentagon (``sharpened``'s ``loose``)
# px inside every side of the seen outline: there the seen region's own outline is an
# occluder's notch, which the outline follows (a box's corner reaching into the sheet)
NOTCH_PX = 4.0
_ROLL5 = [np.roll(np.arange(5), -k) for k in range(5)]  # np.roll(p, -k, axis=0) of 5 corners


@dataclass(frozen=True, eq=False)
class Partial:
    """
    A four-corner hypothesis whose fourth corner (index 3) is hidden.

    :param corners: (4, 2) px, corners 0..2 seen, 3 extrapolated (cyclic order).
    :param seen_ends: (4, 2, 2) px, the seen part of each side ``i`` (corner ``i`` to ``i+1``).
    :param seen_frac: (2,) seen fraction of the two sides at the hidden corner (sides 2, 3).
    :param outline: (M, 2) px, the seen region's outline, when the hypothesis needs it.
    """

    corners: Array
    seen_ends: Array
    seen_frac: Array
    outline: Array | None = None


def pentagon(contour: npt.NDArray[np.int32]) -> Array | None:
    """Return the (5, 2) simplified convex hull of a contour when it has five vertices."""
    return lines.rough_polygon(contour, 5, (0.01, 0.02, 0.03))


def sharp_pentagon(contour: npt.NDArray[np.int32], plain: Array | None) -> Array | None:
    """
    Return the hull simplified finely with its blunted corners sharpened (``sharpened``, the
    loose rule only where the strict one leaves no five vertices: it would also take a short
    occluder's cut for a blunted corner) when that leaves five vertices and differs from
    ``plain`` (the contour's ``pentagon``). A small sheet in the work image has every corner
    cut by one short edge, so a five-vertex simplification either spends a vertex on a
    blunted corner or drops the occluder's cut.
    """
    hull = cv2.convexHull(contour)
    fine = cv2.approxPolyDP(hull, FINE_FRAC * cv2.arcLength(hull, True), True)
    fine = fine.reshape(-1, 2).astype(np.float64)
    sharp = sharpened(fine)
    if sharp is None or len(sharp) != 5:
        sharp = sharpened(fine, loose=True)
    if sharp is None or len(sharp) != 5:
        return None
    if plain is not None and any(np.abs(sharp[_ROLL5[k]] - plain).max() <= 2.0
                                 for k in range(5)):
        return None
    return sharp


def sharpened(poly: Array, loose: bool = False) -> Array | None:
    """
    Return a convex polygon (N, 2) with each blunted corner (an edge shorter than
    ``BLUNT_FRAC`` of both its neighbours, and than ``BLUNT_PX``) replaced by the meeting
    point of its neighbours, shortest first; None when a meeting point is not near.
    ``loose``: shorter than ``BLUNT_FRAC`` of the longer neighbour only. (A sheet of 0.5 %
    of the image with a box on one corner: the sides at the hidden corner show 10-14 work px
    up to the box, and the blunted corners next to them, 5-7 px, are more than ``BLUNT_FRAC``
    of that: seeds 73, 74.)
    """
    poly = poly.copy()
    while len(poly) > 4:
        n = len(poly)
        # (np.roll's order, indexed: the same values, cheaper)
        prev, nxt = np.arange(n) - 1, (np.arange(n) + 1) % n
        ln = np.hypot(*(poly[nxt] - poly).T)
        near = np.maximum(ln[prev], ln[nxt]) if loose else np.minimum(ln[prev], ln[nxt])
        short = (ln < BLUNT_PX) & (ln < BLUNT_FRAC * near)
        if not short.any():
            return poly
        e = int(np.argmin(np.where(short, ln, np.inf)))
        centre = poly.mean(axis=0)
        meet = lines.intersect(lines.line_through(poly[(e - 1) % n], poly[e], centre),
                               lines.line_through(poly[(e + 1) % n], poly[(e + 2) % n], centre))
        if meet is None or np.hypot(*(meet - poly[e])) > 2.0 * BLUNT_PX:
            return None
        poly[e] = meet
        poly = np.delete(poly, (e + 1) % n, axis=0)
    return poly


def hypotheses(poly: Array, min_seen: float) -> list[Partial]:
    """
    Return hidden-corner hypotheses of a convex pentagon (5, 2), one per plausible cut side.

    Cut side ``(p3, p4)``: the corner is the intersection of lines ``p2 p3`` and ``p4 p0``,
    beyond the cut, with ``|p2 p3| >= min_seen |p2 corner|`` and likewise for ``p4 p0``.
    """
    out = []
    centre = poly.mean(axis=0)
    # Edge e runs from poly[e] to poly[e + 1]; each hypothesis uses three of the five lines.
    edges = [lines.line_through(poly[e], poly[(e + 1) % 5], centre) for e in range(5)]
    for k in range(5):
        corner = lines.intersect(edges[(k + 4) % 5], edges[(k + 1) % 5])  # p2 p3, p4 p0
        if corner is None:
            continue
        cut = edges[k]
        if cut[:2] @ corner + cut[2] <= 1.0:
            continue  # not beyond the cut: these sides do not meet at a hidden corner
        p = poly[_ROLL5[(k + 2) % 5]]  # p[3], p[4]: the cut (edge k)
        frac = np.array([np.hypot(*(p[3] - p[2])) / max(np.hypot(*(corner - p[2])), 1e-9),
                         np.hypot(*(p[0] - p[4])) / max(np.hypot(*(p[0] - corner)), 1e-9)])
        if frac.min() < min_seen or frac.max() > 1.0:
            continue
        corners = np.array([p[0], p[1], p[2], corner])
        ends = np.array([[p[0], p[1]], [p[1], p[2]], [p[2], p[3]], [p[4], p[0]]])
        out.append(Partial(corners, ends, frac))
    return out


def rough_sides(hyp: Partial) -> tuple[Array, int]:
    """(4, 3) lines through the seen side ends (oriented by the centre) and profiles per side."""
    centre = hyp.corners.mean(axis=0)
    rough = np.array([lines.line_through(a, b, centre) for a, b in hyp.seen_ends])
    seen_len = np.linalg.norm(hyp.seen_ends[:, 1] - hyp.seen_ends[:, 0], axis=1)
    return rough, int(np.clip(seen_len.mean() / 4.0, 16, 64))


def finish(hyp: Partial, out: sides.Refined, band_px: float, hidden_slack: float = 1.0
           ) -> tuple[Array, Array, Array, Array, Array, Array] | None:
    """
    Intersect a hypothesis's sides, refined along their seen parts (``out``, from
    ``sides.refine_many``). Each corner may move from the rough one by twice the band and
    4 px, the hidden one ``hidden_slack`` times that.

    :returns: ((4, 2) corners, (4,) supports, (4,) colour steps, (4, 3) inside colours,
        (4, 3) outside colours, (5, 2) outline of the seen part) or None.
    """
    refined, supports, steps, inside, outside = out
    corners = lines.quad_corners(list(refined))
    if corners is None or not cv2.isContourConvex(corners.astype(np.float32)):
        return None
    reach = (2.0 * band_px + 4.0) * np.array([1.0, 1.0, 1.0, hidden_slack])
    if (np.abs(corners - hyp.corners).max(axis=1) > reach).any():
        return None
    # The seen outline: the cut points moved onto the refined sides.
    cuts = [hyp.seen_ends[2, 1], hyp.seen_ends[3, 0]]
    cuts = [q - (refined[s, :2] @ q + refined[s, 2]) * refined[s, :2]
            for s, q in zip((2, 3), cuts)]
    outline = np.array([corners[0], corners[1], corners[2], cuts[0], cuts[1]])
    return corners, supports, steps, inside, outside, outline


def _deep_run(region: Array, depth: Array) -> tuple[Array, Array] | None:
    """
    Return the longest run of the closed outline ``region`` (M, 2) whose points lie more than
    ``NOTCH_PX`` inside every side (``depth`` (M, S) px inside each), and its depths; None
    when no point or every point does.
    """
    deep = depth.min(axis=1) > NOTCH_PX
    if not deep.any() or deep.all():
        return None
    start = int(np.argmin(deep))  # (from the first point after a shallow one)
    rolled = np.roll(deep, -start)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], rolled.astype(int), [0]])))
    a, e = max(zip(edges[::2], edges[1::2]), key=lambda r: r[1] - r[0])
    return np.roll(region, -start, axis=0)[a:e], np.roll(depth, -start, axis=0)[a:e]


def clipped(corners: Array, region: Array) -> Array | None:
    """
    Return the seen outline of a sheet whose corner 3 is hidden: the refined quad ``corners``
    (4, 2) with the corner cut off along the longest stretch of the seen ``region``'s outline
    (M, 2, dense) running more than ``NOTCH_PX`` inside all four sides (the occluder's
    edge, straight or notched), its ends moved onto the sides nearest them, then round the
    seen corners the way that leaves corner 3 out; None when that stretch leaves and comes
    back on one side. (The hidden-corner paths' own seen outline joins the two sides' rough
    seen ends by a chord: on pages under a box it drew the cut over the box and left seen
    page out.) A stretch that does not end on sides 2 and 3 cuts off a part that is not the
    region seen: ``detect_sheet._follow_notches`` refuses it by its area.
    """
    ls = lines.side_lines(corners)
    deep = _deep_run(region, lines.depths_inside(region, ls))
    if deep is None:
        return None
    run, depth = deep
    s0, s1 = (int(np.argmin(d)) for d in depth[[0, -1]])
    if s0 == s1:
        return None
    # Round the seen corners from the side the stretch ends on to the one it starts on. The
    # two ways round share no corner and hold all four: exactly one leaves corner 3 out.
    fwd = [(s1 + 1 + i) % 4 for i in range((s0 - s1) % 4)]
    back = [(s1 - i) % 4 for i in range((s1 - s0) % 4)]
    keep = back if 3 in fwd else fwd
    # (each end moved onto its side: where the occluder's edge meets it)
    ends = [q - (ls[k, :2] @ q + ls[k, 2]) * ls[k, :2] for k, q in ((s0, run[0]), (s1, run[-1]))]
    return np.vstack([ends[0], run, ends[1], corners[keep]])


def snapped(corners: Array, region: Array) -> Array:
    """
    Return the outline (N, 2) px of one seen part of a sheet with the refined quad
    ``corners`` (4, 2): its region's outline (M, 2, dense) with the points within
    ``NOTCH_PX`` of a side (or beyond it) moved onto that side, and a corner put in
    between two such points on neighbouring sides. (The whiteness region's outline lies a
    work pixel or so off the sides; what runs deeper is an occluder's edge.)
    """
    ls = lines.side_lines(corners)
    depth = lines.depths_inside(region, ls)  # (M, 4)
    side = np.argmin(depth, axis=1)
    near = depth[np.arange(len(region)), side] <= NOTCH_PX
    pts = region.copy()
    pts[near] += depth[near, side[near], None] * ls[side[near], :2]
    out = []
    for j, k in zip(range(len(pts)), np.roll(np.arange(len(pts)), -1)):
        out.append(pts[j])
        a, b = side[j], side[k]
        if near[j] and near[k] and b == (a + 1) % 4:
            out.append(corners[b])  # (side a ends at corner a + 1)
        elif near[j] and near[k] and a == (b + 1) % 4:
            out.append(corners[a])
    return np.array(out)


def notched(poly: Array, region: Array) -> Array:
    """
    Return the seen outline ``poly`` (5, 2) (three seen corners, then the cut points on the
    two sides at the hidden corner) with its cut replaced by the longest stretch of the seen
    ``region``'s outline (M, 2) running more than ``NOTCH_PX`` inside all its sides, when
    that stretch begins and ends nearer the cut than any other side: an occluder reaching
    into the sheet (a box's corner in front of it) is not outlined as sheet. (A stretch
    ending elsewhere is a corner the region's outline rounds off.)
    """
    ls = lines.side_lines(poly)
    depth = lines.depths_inside(region, ls)  # (M, 5)
    # (a cut at a seen corner, a placed stub's, adds no side)
    depth[:, np.hypot(*(np.roll(poly, -1, 0) - poly).T) < 1e-6] = np.inf
    deep = _deep_run(region, depth)
    if deep is None:
        return poly
    run, depth = deep
    if (np.argmin(depth[[0, -1]], axis=1) != 3).any():
        return poly
    if np.hypot(*(run[0] - poly[3])) > np.hypot(*(run[-1] - poly[3])):
        run = run[::-1]  # from the cut on side 2 to the one on side 3
    return np.vstack([poly[:4], run, poly[4:]])
