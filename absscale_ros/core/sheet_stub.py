"""
A sheet whose hidden corner takes most of one side with it: three corners from intrinsics.

An object on the sheet that covers one corner often also covers nearly all of one side next
to it: the region seen is the two whole sides meeting at the opposite corner, part of the
third side, and only a short stub of the fourth at its seen end (``sheet_partial`` needs both
sides at the hidden corner seen over a good part of their length to intersect them). With the
camera intrinsics the fourth side's direction is known without seeing it: in 3D it is parallel
to the whole side opposite it, so its vanishing point is where the plane's other direction
(from the two sides known to be parallel, the whole one and the partly seen one) meets that
side's back-projected plane at a right angle. The stub is then refined only along its first
few pixels, to give the third seen corner from image evidence (a stub with no edge is
refused), and the hidden corner is where the predicted fourth side meets the third side.
"""
import dataclasses

import numpy as np
import numpy.typing as npt

from absscale_ros.core import lines, sheet_candidates, sheet_partial, sides

Array = npt.NDArray[np.float64]
STUB_MAX_DEG = 8.0  # largest angle between the stub's edge and the side predicted there
STUB_AGREE = 0.05  # largest distance of the stub's corner from the predicted one, of the side
STUB_MIN_SUPPORT = 0.99  # every profile of the stub must find its edge on the fitted line
OCCLUDER_DEPTH = 0.1  # of the shorter hidden side: how far inside an occluder's edge must cut
SHORT_EDGE = 0.25  # polygon edges shorter than this fraction of a side are a blunted corner
# Sides checked after that pass: not the stub (2), whose wide profiles near the corner still
# catch the whole side's edge.
CHECKED = np.array([0, 1, 3])
FINE_BANDS = sheet_partial.FINE_BANDS  # refinement passes after the widest
SCREEN_SLACK = 3.0  # ``finish``'s slack after the widest pass: half the hypotheses go there


def _cross(a: Array, b: Array) -> Array:
    """Cross product of two 3-vectors (numpy's is slow on single vectors)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                     a[0] * b[1] - a[1] * b[0]])


def side_vanishing(l_whole: Array, l_part: Array, l_between: Array, K: Array) -> Array | None:
    """
    Return the homogeneous vanishing point of the sides parallel (in 3D) to ``l_between``.

    ``l_whole`` and ``l_part`` are opposite sides (parallel in 3D) both meeting
    ``l_between``; the other pair's 3D direction is perpendicular to theirs and lies in the
    plane through the camera centre and ``l_between``.
    """
    v1 = _cross(l_whole, l_part)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    d1 = np.array([(v1[0] - cx * v1[2]) / fx, (v1[1] - cy * v1[2]) / fy, v1[2]])  # K^-1 v1
    d2 = _cross(d1, K.T @ l_between)
    v2 = K @ d2
    return None if not np.isfinite(v2).all() or np.abs(v2).max() < 1e-12 else v2


def hidden_corner(corner: Array, towards: Array, vanish: Array, l_part: Array) -> Array | None:
    """
    Return where the side from ``corner`` to its vanishing point ``vanish`` meets ``l_part``;
    the side leaves ``corner`` on the side of ``towards`` (a point along it, px).
    """
    hit = _cross(_cross(np.array([corner[0], corner[1], 1.0]), vanish), l_part)
    if abs(hit[2]) < 1e-12:
        return None
    out = hit[:2] / hit[2]
    return out if (out - corner) @ (towards - corner) > 0.0 else None


def occluded(corners: Array, outline: Array, min_depth: float = 0.1) -> bool:
    """
    Return True when the seen region's outline cuts well inside the triangle T R B of the
    hypothesis (corners B, L, T, R): an occluder's edge. A whole object whose corner is only
    blurred or dim instead runs along the predicted sides T R and R B there.
    """
    return occluder_depth(corners, outline) >= min_depth


def occluder_depth(corners: Array, outline: Array) -> float:
    """
    Return how far (over the shorter hidden side) the outline (M, 2) reaches inside the
    triangle T R B of corners B, L, T, R, away from both sides T R and R B.
    """
    b, _, t, r = corners
    inside = np.ones(len(outline), dtype=bool)
    for p0, p1, opposite in ((t, r, b), (r, b, t), (b, t, r)):
        line = lines.line_through(p0, p1, opposite)
        inside &= outline @ line[:2] + line[2] < 0.0
    if not inside.any():
        return 0.0
    pts = outline[inside]
    dist = [np.abs(pts @ ln[:2] + ln[2])
            for ln in (lines.line_through(t, r, b), lines.line_through(r, b, t))]
    side = min(np.hypot(*(r - t)), np.hypot(*(r - b)))
    return float(np.minimum(*dist).max()) / max(side, 1e-9)


def far_corners(corner_l: Array, b: Array, l_lt: Array, l_rb: Array, K: Array,
                aspect: float) -> list[Array]:
    """
    Return the two places (side L B short or long) where the rectangle of ``aspect`` puts the
    far end T of side L T, from corners L and B and the lines L T and R B (parallel in 3D).
    """
    # One solve for the three right-hand sides (the same LU, the same numbers as three).
    d1, r_l, r_b = np.linalg.solve(K, np.array([
        _cross(l_lt, l_rb), [corner_l[0], corner_l[1], 1.0], [b[0], b[1], 1.0]]).T).T
    if abs(float(r_b @ d1)) < 1e-12:
        return []
    x_b = (r_l @ d1) / (r_b @ d1) * r_b  # L B perpendicular to d1, depth of L at 1
    width = float(np.linalg.norm(x_b - r_l))
    d1 = d1 / np.linalg.norm(d1)
    out = []
    for length in (width * aspect, width / aspect):
        for sign in (1.0, -1.0):
            x_t = r_l + sign * length * d1
            if x_t[2] > 1e-9:
                out.append((K @ x_t)[:2] / (K @ x_t)[2])
    return out


def polygons(contour: npt.NDArray[np.int32], grow_px: float = 0.0) -> list[Array]:
    """
    Return the contour's simplified convex hulls with four to six vertices, every side moved
    ``grow_px`` outwards.
    """
    out = []
    for n in (4, 5, 6):
        poly = lines.rough_polygon(contour, n, (0.01, 0.02, 0.03))
        poly = None if poly is None else sheet_candidates.offset(poly, grow_px)
        if poly is not None:
            out.append(poly)
    return out


def dense(points: Array, step_px: float = 2.0) -> Array:
    """Return a closed polyline (N, 2) with points at most about ``step_px`` apart (contours
    keep only the ends of straight runs, and an occluder's straight edge is one)."""
    ends = np.roll(points, -1, axis=0)
    counts = np.maximum(np.ceil(np.hypot(*(ends - points).T) / step_px), 1).astype(int)
    frac = np.concatenate([np.arange(c) / c for c in counts])
    start = np.repeat(np.arange(len(points)), counts)
    return points[start] + frac[:, None] * (ends[start] - points[start])


def first_hypotheses(regions: list[tuple[npt.NDArray[np.int32], float]], scale: float,
                     K: Array, stub_px: float, max_hyps: int) -> list[sheet_partial.Partial]:
    """
    Return the first ``max_hyps`` distinct hypotheses of work-image regions (contour, grow px)
    whose rough outline already shows an occluder (half the depth ``refine`` asks of the
    refined one), in full-resolution px (work px / ``scale``).
    """
    out: list[sheet_partial.Partial] = []
    polys: list[Array] = []
    for contour, grow in regions if max_hyps > 0 else ():
        outline = None  # made once a polygon of the region is new (most repeat another mask's)
        for poly in polygons(contour, grow):
            if any(len(q) == len(poly) and np.abs(q - poly).max() <= 2.0 for q in polys):
                continue  # the same outline from another mask
            polys.append(poly)
            if outline is None:
                outline = lines.full_px(dense(contour.reshape(-1, 2).astype(np.float64)), scale)
            for h in hypotheses(lines.full_px(poly, scale), K, stub_px, outline):
                if any(np.abs(h.corners[:3] - o.corners[:3]).max() <= 6.0 for o in out):
                    continue
                if occluder_depth(h.corners, outline) >= 0.5 * OCCLUDER_DEPTH:
                    out.append(h)
                    if len(out) == max_hyps:
                        return out
    return out


def hypotheses(poly: Array, K: Array, stub_px: float, outline: Array | None = None
               ) -> list[sheet_partial.Partial]:
    """
    Return hidden-corner hypotheses of a convex polygon (N, 2) px in which one side is only a
    stub: for every edge taken as the whole side between two seen corners B (first) and L,
    the next long edge is the whole side L T and the previous one the partly seen side
    towards B; T is the far end of L T. Both polygon orientations are tried, the longest
    pair of whole sides first. ``outline`` (M, 2) px: the seen region's outline, for the
    occluder test of ``refine``.
    """
    out = []
    for p in (poly, poly[::-1]):
        n = len(p)
        length = np.hypot(*(np.roll(p, -1, axis=0) - p).T)
        ls = lines.side_lines(p)
        for j in range(n):
            k = (j + 1) % n
            if length[k] < SHORT_EDGE * length[j]:
                k = (k + 1) % n  # skip a blunted corner
            i = (j - 1) % n
            if len({i, j, k}) < 3 or (k + 1) % n == i:
                continue  # a whole quadrilateral: not this case
            hyp = _hypothesis(p, ls, i, j, k, K, stub_px)
            if hyp is not None:
                out.append((length[j] + length[k], len(out),
                            dataclasses.replace(hyp, outline=outline)))
    return [h for *_, h in sorted(out, key=lambda x: (-x[0], x[1]))]


def _hypothesis(p: Array, ls: Array, i: int, j: int, k: int, K: Array, stub_px: float
                ) -> sheet_partial.Partial | None:
    """Edges ``i`` (part of side R B), ``j`` (B L), ``k`` (L T) of polygon ``p`` (lines ``ls``)."""
    n = len(p)
    li, lj, lk = ls[i], ls[j], ls[k]
    b, corner_l = lines.intersect(li, lj), lines.intersect(lj, lk)
    if b is None or corner_l is None:
        return None
    t = p[(k + 1) % n] - (lk[:2] @ p[(k + 1) % n] + lk[2]) * lk[:2]  # the end of L T on it
    vanish = side_vanishing(lk, li, lj, K)
    if vanish is None:
        return None
    r = hidden_corner(t, t + (b - corner_l), vanish, li)
    if r is None:
        return None
    cut_start = p[i]  # where the seen part of R B begins
    seen_rb = float(np.hypot(*(b - cut_start)))
    rb = float(np.hypot(*(b - r)))
    tr = float(np.hypot(*(r - t)))
    if not 0.0 < seen_rb < rb or tr <= 2.0 * stub_px:
        return None
    stub_end = t + stub_px * (r - t) / tr
    corners = np.array([b, corner_l, t, r])
    ends = np.array([[b, corner_l], [corner_l, t], [t, stub_end], [cut_start, b]])
    return sheet_partial.Partial(corners, ends, np.array([stub_px / tr, seen_rb / rb]))


def finish(hyp: sheet_partial.Partial, out: sides.Refined, band_px: float, K: Array,
           aspect: float | tuple[float, ...], slack: float = 1.0
           ) -> tuple[Array, Array, Array, Array, Array, Array] | None:
    """
    Corners of a stub hypothesis from its sides, refined along their seen parts (``out``,
    from ``sides.refine_many``): the seen corners are intersections of refined sides, the
    hidden one is where the predicted fourth side (through the third corner) meets the third
    side, not the stub's own poorly determined direction. The stub's corner must agree with
    the one the sheet's ``aspect`` (long / short side) puts at the end of its whole side: an
    occluder's edge a few pixels past the corner pulls a stub's corner off (several aspects:
    any of them). A stub whose edge is not along the predicted side (the occluder's edge runs
    through the corner itself) gives no sheet: the corner the aspect alone places at the end
    of the whole side moves a quarter of that side or more per pixel of the seen sides (the
    vanishing geometry of two short sides), 0.9 % of the side off in the median on the pages
    under a box (seeds 80-86, 21 detections; up to 6 %), and nothing seen predicted which
    (a wrong corner is worse than none: the SfM trusts it). ``slack`` > 1: a screen
    after the widest pass only: the stub's edge, and so the third corner, are not settled yet,
    so neither is checked, and the occluder may cut ``slack`` times less deep.

    :returns: ((4, 2) corners, (4,) supports, (4,) colour steps, (4, 3) inside colours,
        (4, 3) outside colours, (5, 2) outline of the seen part) or None.
    """
    ls, supports, steps, inside, outside = out
    seen = [lines.intersect(ls[a], ls[b]) for a, b in ((3, 0), (0, 1), (1, 2))]
    if any(c is None for c in seen):
        return None
    b, corner_l, t = seen
    reach = 2.0 * band_px + 4.0  # how far refined corners may move from the rough ones
    if max(np.hypot(*(c - h)) for c, h in zip(seen[:2], hyp.corners[:2])) > reach:
        return None
    vanish = side_vanishing(ls[1], ls[3], ls[0], K)
    if vanish is None:
        return None
    r = hidden_corner(t, hyp.corners[3], vanish, ls[3])
    t_pred = [p for a in ((aspect,) if isinstance(aspect, float) else aspect)
              for p in far_corners(corner_l, b, ls[1], ls[3], K, a)]
    side = float(np.hypot(*(t - corner_l)))
    max_sin = np.sin(np.deg2rad(STUB_MAX_DEG))
    # The stub's edge counts when every profile finds it (not a stray edge point on a few
    # pixels of side) along the predicted side (not the occluder's own edge).
    if not (slack > 1.0 or supports[2] >= STUB_MIN_SUPPORT and r is not None and abs(
            float(ls[2, :2] @ (r - t))) <= max_sin * np.hypot(*(r - t))):
        return None
    if slack == 1.0 and np.hypot(*(t - hyp.corners[2])) > reach:
        return None  # (not in the screen: an occluder's edge may still move it)
    if slack == 1.0 and (not t_pred or min(np.hypot(*(t - p)) for p in t_pred)
                         > STUB_AGREE * side + 0.5):
        return None  # the stub's corner is not where the sheet's shape puts it
    if r is None or np.hypot(*(r - b)) <= np.hypot(*(hyp.seen_ends[3, 0] - b)):
        return None  # the hidden corner must lie beyond the part of its side that is seen
    # A few pixels of side next to a corner and an occluder give no fair sample of the
    # colours on either side of it: the one-colour tests use the other three sides.
    inside, outside = inside.copy(), outside.copy()
    inside[2] = np.median(inside[[0, 1, 3]], axis=0)
    outside[2] = np.median(outside[[0, 1, 3]], axis=0)
    corners = np.array([b, corner_l, t, r])
    if hyp.outline is not None and not occluded(corners, hyp.outline, OCCLUDER_DEPTH / slack):
        return None
    cuts = [hyp.seen_ends[2, 1], hyp.seen_ends[3, 0]]  # the cut points moved onto the sides
    cuts = [q - (ls[s, :2] @ q + ls[s, 2]) * ls[s, :2] for s, q in zip((2, 3), cuts)]
    outline = np.array([b, corner_l, t, cuts[0], cuts[1]])
    return corners, supports, steps, inside, outside, outline
