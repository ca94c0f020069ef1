"""
Cube faces of which the image border leaves one corner: a triangle along the border.

Near the border a face can show one corner only, its two sides leaving it running to the
border. The mask opening rounds that acute corner, so the region's rough quad has one side
along the border and, opposite, a side a few px long between two corners that are the
rounding's (``lines.rough_quad``): refined as a quad, the face fails. Its two real sides meet
at a cube vertex, which the face's colour names; it poses nothing (no whole side), but its
outline confirms a pose posed on another face, and its colour is seen at that vertex.

A tip face is a ``Face`` cut along side ``cut`` (corners ``cut`` and ``cut + 1`` where the
real sides meet the border) whose corners ``cut + 2`` and ``cut + 3`` are both the seen
corner; its side line ``cut + 2`` repeats side ``cut + 3`` (so the seen corner's two lines
are the real sides: ``cube_assembly`` measures corner ``cut + 2`` only).
"""
from typing import TYPE_CHECKING, Callable

import numpy as np
import numpy.typing as npt

from absscale_ros.core import cube_border, lines, sides

if TYPE_CHECKING:
    from absscale_ros.core.detect_cube import Face

Array = npt.NDArray[np.float64]


def tip_faces(image_bgr: npt.NDArray[np.uint8], rough: list[tuple[str, Array, Array]],
              refined: list['Face | None'],
              border_side: Callable[[Array, int, int], tuple[int, Array] | None],
              make: Callable[..., 'Face'], max_frac: float, min_step: float,
              min_support: float, max_ramp_px: float) -> list[tuple[int, 'Face']]:
    """
    Return (rough face index, its tip face) of the rough faces along the border that are tip
    faces: refined as a quad, such a face fails or keeps the rounding's two corners.

    :param rough: (colour, (4, 3) Hough side lines, (4, 2) rough quad px) per face.
    :param refined: per rough face its refined face, or None.
    :param border_side: (quad, w, h) -> (side index, the border's line) of the one side along
        the border, or None (``detect_cube._border_side``).
    :param make: ``Face``'s constructor.
    :param max_frac: the side opposite the border is at most this fraction of the shorter
        side leaving it.
    :param min_step: smallest colour step across each real side, ``min_support`` smallest
        support (as a face's).
    :param max_ramp_px: a real side ramping (25-75 %) over more (motion blur) gives none.
    """
    h, w = image_bgr.shape[:2]
    cands = _candidates(rough, refined, border_side, max_frac, w, h)
    if not cands:
        return []
    # Per candidate its two real sides (c + 1, c + 3), refined as a face's are.
    ls = np.array([rough[f][1][(c + k) % 4] for f, c, _ in cands for k in (1, 3)])
    ends = cube_border.clip_ends(np.array([[rough[f][2][(c + k) % 4], rough[f][2][(c + k + 1) % 4]]
                                           for f, c, _ in cands for k in (1, 3)]), w, h)
    n = int(np.clip(np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1).max() / 3.0, 12, 48))
    refd, support, steps, inside, outside = sides.refine(image_bgr, ls, ends, (6.0, 4.0, 2.5), n)
    ramps = sides.ramp_widths(image_bgr, refd, ends, 6.0, inside, outside)
    out = []
    for j, (f, c, border) in enumerate(cands):
        a, b = refd[2 * j], refd[2 * j + 1]  # sides c + 1 (from the border) and c + 3 (to it)
        pair = slice(2 * j, 2 * j + 2)
        if steps[pair].min() < min_step or support[pair].min() < min_support or \
                ramps[pair].max() > max_ramp_px:
            continue
        quad = rough[f][2]
        tip, first, last = lines.intersect(a, b), lines.intersect(border, a), \
            lines.intersect(border, b)
        if tip is None or first is None or last is None or \
                cube_border.outside(tip[None], w, h)[0]:
            continue
        rough_corners = np.array([quad[c], quad[(c + 1) % 4],
                                  0.5 * (quad[(c + 2) % 4] + quad[(c + 3) % 4])])
        side = np.hypot(*(rough_corners[2] - rough_corners[:2]).T).max()
        if np.hypot(*(np.array([last, first, tip]) - rough_corners).T).max() > \
                max(4.0, 0.25 * side):
            continue  # the sides meet elsewhere: not one rounded corner
        corners, side_lines = np.zeros((4, 2)), np.zeros((4, 3))
        corners[[c, (c + 1) % 4, (c + 2) % 4, (c + 3) % 4]] = last, first, tip, tip
        side_lines[[c, (c + 1) % 4, (c + 2) % 4, (c + 3) % 4]] = border, a, b, b
        sup = np.full(4, support[pair].min())
        sup[(c + 1) % 4], sup[(c + 3) % 4] = support[pair]
        out.append((f, make(rough[f][0], corners, side_lines, sup, cut=c, tip=True)))
    return out


def _candidates(rough: list[tuple[str, Array, Array]], refined: list['Face | None'],
                border_side: Callable[[Array, int, int], tuple[int, Array] | None],
                max_frac: float, w: int, h: int) -> list[tuple[int, int, Array]]:
    """(rough index, cut side, the border's line) of the rough faces refined as none or as a
    cut face whose rough quad has one side along the border and, opposite, a side at most
    ``max_frac`` of the shorter side leaving it (the rounding's; see ``tip_faces``)."""
    cands = []
    for f, ((_, _, quad), face) in enumerate(zip(rough, refined)):
        cut = border_side(quad, w, h) if face is None or face.cut >= 0 else None
        if cut is None:
            continue
        c = cut[0]
        length = np.hypot(*(quad[[1, 2, 3, 0]] - quad).T)
        if length[(c + 2) % 4] <= max_frac * min(length[(c + 1) % 4], length[(c + 3) % 4]):
            cands.append((f, c, cut[1]))
    return cands
