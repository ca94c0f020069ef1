"""
Cube faces joined with an object of their own colour: one mask region, cut back into faces.

A box of a cube colour standing behind the cube, or against it, joins the face of that
colour in the colour mask: the region fails the face tests, or passes them but is no
quadrilateral, and the cube is lost. A cube face is one flat colour, so the region is cut
where that is no longer true, by either of two cues:

- a shading edge: the other object's face turns another way to the light, so Canny finds the
  line between them although the colour mask does not;
- a concave corner: where no edge shows (two parallel faces, the same shade), the region's
  outline turns inwards where the face's side meets the other object's; the face's side goes
  on straight through the region from there, so the region is cut along it (either of the
  two outline sides meeting at that corner).

Of the cuts tried, the one whose pieces that pass the face tests are best explained as
quadrilaterals (their pixels in their rough quads, less those quads' pixels not theirs)
wins: a cut beside the face's true side leaves a piece that passes the tests, but with a
notch or a bump its quad does not have.

Only run when a frame's regions give no cube (``detect_cube.detect_cubes``); the pieces are
refined and checked like any face, so a wrong cut (no colour step along it) drops out there.
"""
from typing import Callable

import cv2
import numpy as np
import numpy.typing as npt

Contour = npt.NDArray[np.int32]
FIT_PX = 8  # outline points (work px) fitted for a side leaving a concave corner
SKIP_PX = 2  # outline points next to the corner left out of that fit (rounded by the opening)
MAX_CORNERS = 2  # deepest concave corners of a region tried


def split(contour: Contour, mask: npt.NDArray[np.uint8], work_bgr: npt.NDArray[np.uint8],
          face_quad: Callable[[Contour], npt.NDArray[np.float64] | None],
          canny: tuple[float, float],
          min_depth_px: float, passes: int) -> list[Contour]:
    """
    Return the outlines (work px) of the pieces of a mask region that pass the face tests
    (``face_quad``: its rough quad, or None): the region cut along its Canny edges, and each
    piece cut again along the side at a concave corner that best improves its quad fit.

    :param contour: the region's outline in ``mask`` (the opened colour mask, work px);
        ``work_bgr`` the work image the mask was made from.
    :param canny: (low, high) Canny thresholds of the shading-edge cut.
    :param min_depth_px: shallowest concave corner cut along, work px.
    :param passes: 3x3 openings after a cut, as many as the colour mask's own (they part the
        thin bridges a cut leaves).
    """
    x, y, w, h = cv2.boundingRect(contour)
    x0, y0 = max(x - 2, 0), max(y - 2, 0)
    x1, y1 = min(x + w + 2, mask.shape[1]), min(y + h + 2, mask.shape[0])
    own = np.zeros((y1 - y0, x1 - x0), np.uint8)
    cv2.drawContours(own, [contour], -1, 255, cv2.FILLED, offset=(-x0, -y0))
    own &= mask[y0:y1, x0:x1]
    edges = cv2.Canny(work_bgr[y0:y1, x0:x1], *canny)
    # An 8-connected edge line leaves diagonal gaps: widen it before cutting.
    cut = own & ~cv2.dilate(edges, np.ones((2, 2), np.uint8))
    kernel = np.ones((3, 3), np.uint8)
    cut = cv2.morphologyEx(cut, cv2.MORPH_OPEN, kernel, iterations=passes)
    out = []
    for piece in _regions(cut):
        best, best_score = _passing([piece], face_quad, cut.shape)
        alone = np.zeros_like(cut)
        cv2.drawContours(alone, [piece], -1, 255, cv2.FILLED)
        alone &= cut
        for p, d in _concave_sides(piece, min_depth_px):
            far = p + d * float(w + h)
            lined = alone.copy()
            cv2.line(lined, tuple(int(v) for v in np.round(p)),
                     tuple(int(v) for v in np.round(far)), 0, 2)
            lined = cv2.morphologyEx(lined, cv2.MORPH_OPEN, kernel, iterations=passes)
            found, score = _passing(_regions(lined), face_quad, cut.shape)
            if score > best_score:
                best, best_score = found, score
        out += best
    return [c + np.array([x0, y0], np.int32) for c in out]


def _passing(contours: list[Contour],
             face_quad: Callable[[Contour], npt.NDArray[np.float64] | None],
             shape: tuple[int, ...]) -> tuple[list[Contour], float]:
    """Return the outlines that pass the face tests, and the sum of their quad fits."""
    found, score = [], 0.0
    for c in contours:
        quad = face_quad(c)
        if quad is not None:
            found.append(c)
            score += _quad_fit(c, quad, shape)
    return found, score


def _quad_fit(contour: Contour, quad: npt.NDArray[np.float64], shape: tuple[int, ...]
              ) -> float:
    """Return a region's pixels inside its rough quad less the quad's pixels outside it."""
    region = np.zeros(shape[:2], np.uint8)
    cv2.drawContours(region, [contour], -1, 1, cv2.FILLED)
    inside = np.zeros_like(region)
    cv2.fillPoly(inside, [np.round(quad).astype(np.int32).reshape(-1, 1, 2)], 1)
    both = cv2.countNonZero(region & inside)
    return float(2 * both - cv2.countNonZero(inside))


def _regions(mask: npt.NDArray[np.uint8]) -> list[Contour]:
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    return [c for c in contours if len(c) >= 3 * FIT_PX]


def _concave_sides(contour: Contour, min_depth_px: float
                   ) -> list[tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]]:
    """
    Return (point, unit direction into the region) per cut: at each of the deepest concave
    corners of the outline, each of the two outline sides meeting there, carried on.
    """
    pts = contour.reshape(-1, 2).astype(np.float64)
    try:
        hull = cv2.convexHull(contour, returnPoints=False)
        defects = cv2.convexityDefects(contour, hull)
    except cv2.error:  # a self-touching outline
        return []
    if defects is None:
        return []
    defects = defects.reshape(-1, 4)
    defects = defects[defects[:, 3] >= 256.0 * min_depth_px]
    out = []
    n = len(pts)
    for far in defects[np.argsort(-defects[:, 3])][:MAX_CORNERS, 2]:
        for sign in (-1, 1):  # the side before the corner, the side after it
            idx = (far + sign * np.arange(SKIP_PX, SKIP_PX + FIT_PX)) % n
            seg = pts[idx]
            vx, vy = cv2.fitLine(seg.astype(np.float32), cv2.DIST_L2, 0, 0.01, 0.01)[:2, 0]
            d = np.array([vx, vy], np.float64)
            if d @ (pts[far] - seg.mean(axis=0)) < 0:
                d = -d  # from the side towards the corner, and on past it
            out.append((pts[far], d))
    return out
