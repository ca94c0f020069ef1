"""
Cube faces the believed pose shows that the face search missed: their colour's pixels there.

A face of a detected cube can fail the quad search while its pixels are plainly there: a post
in front cuts it across a corner (a five-sided region), a box of its own colour behind it
joins it (the region fails the convexity test), or its sides smear past the refinement. The
cube is still posed on its other faces (``cube_geometry``), and the pose names every face it
shows and, since opposite faces share a colour, each one's colour once two are found. Such a
face is reported as the pixels of its colour inside the posed face (the mask's outline there):
what the colour test and the pose agree on, so neither a box joined to it nor the pose's
error beyond the face's own edges is drawn. It adds an outline only: no vertex comes from it.
"""
from typing import Callable

import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core import targets

Array = npt.NDArray[np.float64]
# (colour, posed face outline (4, 2) px) -> the outline of that colour's pixels in it, or None
FillFn = Callable[[str, Array], Array | None]
# Opposite faces of a posed cube (``cube_geometry.cube_projections``' vertex order: the posing
# face, then the four behind it), each as seen from outside: one colour per pair.
PAIRS = (((0, 1, 2, 3), (7, 6, 5, 4)), ((1, 0, 4, 5), (3, 2, 6, 7)),
         ((2, 1, 5, 6), (0, 3, 7, 4)))
MIN_OWN = 0.5  # a reported face names the shown face holding this share of its area
JOIN_PX = 3  # colour farther than this beyond the posed face is another object's ...
EDGE_MARGIN_PX = 2  # ... and the face's pixels this close to the posed edge there are left out


def missing_faces(proj: Array, reported: list[tuple[str, Array]]) -> list[tuple[str, Array]]:
    """
    Return (colour, (4, 2) outline px) of the faces the posed cube ``proj`` (8, 2) shows whose
    colour no ``reported`` face (colour, outline) has; empty unless the reported faces name two
    of the three opposite pairs' colours without contradiction.
    """
    if {c for c, _ in reported} >= set(targets.CUBE_COLOURS):
        return []  # every colour is reported: none can be missing
    shown = [(p, proj[list(face)]) for p, pair in enumerate(PAIRS) for face in pair]
    # A face is shown when it winds as the posing face does (seen from outside, both).
    turn = [cv2.contourArea(poly.astype(np.float32), oriented=True) for _, poly in shown]
    shown = [(p, poly) for (p, poly), a in zip(shown, turn) if a * turn[0] > 0.0]
    hulls = [cv2.convexHull(poly.astype(np.float32)) for _, poly in shown]
    if not hulls:  # the posing face seen edge-on: no face winds either way
        return []
    colours: dict[int, str] = {}
    for colour, outline in reported:
        found = cv2.convexHull(np.asarray(outline, np.float32))
        area = max(cv2.contourArea(found), 1e-9)
        inter = [cv2.intersectConvexConvex(h, found)[0] for h in hulls]
        best = int(np.argmax(inter))
        if inter[best] < MIN_OWN * area:
            continue
        pair = shown[best][0]
        if colours.get(pair, colour) != colour:
            return []  # two colours on one pair: not the cube this pose says
        colours[pair] = colour
    if len(colours) < 2 or len(set(colours.values())) < len(colours):
        return []
    if len(colours) == 2:
        rest = set(targets.CUBE_COLOURS) - set(colours.values())
        colours[3 - sum(colours)] = rest.pop()
    seen = {c for c, _ in reported}
    return [(colours[p], poly) for p, poly in shown if colours[p] not in seen]


def colour_outline(image_bgr: npt.NDArray[np.uint8], colour: str, face: Array,
                   masks_of: Callable[[npt.NDArray[np.uint8]], dict[str, npt.NDArray[np.bool_]]],
                   min_frac: float) -> Array | None:
    """
    Return the outline px (K, 2) of the largest region of ``colour`` inside the posed face
    outline ``face`` (4, 2) px, through the outer half of its border pixels (a pixel whose
    centre lies inside counts as the face's), or None when it covers under ``min_frac`` of the
    face's pixels within the image.
    """
    h, w = image_bgr.shape[:2]
    m = JOIN_PX + 1  # the crop reaches past the face far enough to see what joins it
    x0, y0 = np.clip(np.floor(face.min(axis=0)).astype(int) - m, 0, [w - 1, h - 1])
    x1, y1 = np.clip(np.ceil(face.max(axis=0)).astype(int) + 1 + m, [x0 + 1, y0 + 1], [w, h])
    inside = np.zeros((y1 - y0, x1 - x0), np.uint8)
    cv2.fillPoly(inside, [np.round((face - [x0, y0]) * 16).astype(np.int32).reshape(-1, 1, 2)],
                 1, shift=4)
    total = cv2.countNonZero(inside)
    colour_px = masks_of(image_bgr[y0:y1, x0:x1])[colour].astype(np.uint8)
    mine = colour_px & inside
    # An object of the colour beside the face (a box behind it) runs on past the pose's
    # tolerance: near it, the posed edge alone bounds the face, so keep a margin from it.
    ring = cv2.dilate(inside, np.ones((2 * JOIN_PX + 1,) * 2, np.uint8))
    beyond = colour_px & (1 - ring)
    if beyond.any():
        k = 2 * (JOIN_PX + EDGE_MARGIN_PX) + 1
        mine &= 1 - cv2.dilate(beyond, np.ones((k, k), np.uint8))
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mine, connectivity=8)
    if n < 2 or total == 0:
        return None
    best = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    if stats[best, cv2.CC_STAT_AREA] < min_frac * total:
        return None
    # Twice the size, each pixel four: the outline through the outer sub-pixels' centres runs
    # a quarter pixel outside the border pixels' centres.
    big = cv2.resize((labels == best).astype(np.uint8), None, fx=2, fy=2,
                     interpolation=cv2.INTER_NEAREST)
    contours, _ = cv2.findContours(big, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    outline = cv2.approxPolyDP(max(contours, key=cv2.contourArea), 1.0, True)
    return outline.reshape(-1, 2) / 2.0 - 0.25 + [x0, y0]
