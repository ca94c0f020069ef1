"""
Cube face sides that are an occluder's edge.

A post in front of the cube cuts a face along the post's edge: that side is straight and the
face stays a quadrilateral, so it looks like a square seen obliquely, and its two corners on
the post are no cube vertices (tens of px from the hidden ones). What tells the post's edge
from a cube edge is that it runs on past both ends of the side, with the post's colour on
the outside, where a cube edge stops at a vertex: past one end at least lie the ground or
another face on both sides of its line. Such a side is treated as the image border's cut
(``Face.cut``): its corners are left out, and the face poses the cube only completed from
its other sides (``cube_geometry.complete_cut``). A post across the middle of a face splits
it into two such pieces, joined back into the face (``join_pieces``).
"""
import dataclasses
from typing import TYPE_CHECKING

import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core import lines

if TYPE_CHECKING:
    from absscale_ros.core.detect_cube import Face

Array = npt.NDArray[np.float64]
NEXT = [1, 2, 3, 0]
SAMPLES = 8  # points read beyond each end of a side
OFFSET_PX = 4.0  # either side of its line (a sharp edge ramps over 1-2 px, a smeared one more)


def occluder_sides(image_bgr: npt.NDArray[np.uint8], side_lines: Array, corners: Array,
                   outside: Array, min_step: float,
                   reach: tuple[float, float] = (0.04, 0.2), min_frac: float = 0.6,
                   max_tilt_deg: float = 20.0) -> npt.NDArray[np.bool_]:
    """
    Return (4,) True for the sides of a face whose edge runs on past both their ends.

    Only sides within ``max_tilt_deg`` of the image's vertical are looked at: a post stands
    upright, while a cube's bottom edge may run on as the edge of its own shadow, or along
    the next face's bottom edge.

    Beyond each end of a side, ``SAMPLES`` points from ``reach`` fractions of its length on
    along its line are read ``OFFSET_PX`` either side of it: the edge runs on where the two
    differ by ``min_step`` at least on ``min_frac`` of the points in the image, and their
    medians too, the outer one nearer the side's ``outside`` colour than the inner one; at
    both ends.

    :param side_lines: (4, 3) the face's side lines, normals pointing out of it.
    :param corners: (4, 2) px, corner i starting side i.
    :param outside: (4, 3) BGR just outside each side.
    """
    return occluder_sides_many(image_bgr, side_lines[None], corners[None], outside[None],
                               min_step, reach, min_frac, max_tilt_deg)[0]


def occluder_sides_many(image_bgr: npt.NDArray[np.uint8], side_lines: Array, corners: Array,
                        outside: Array, min_step: float,
                        reach: tuple[float, float] = (0.04, 0.2), min_frac: float = 0.6,
                        max_tilt_deg: float = 20.0) -> npt.NDArray[np.bool_]:
    """
    Return (F, 4) ``occluder_sides`` of F faces ((F, 4, 3) lines, (F, 4, 2) corners, (F, 4, 3)
    outside colours), all read in one remap: each side's result is its own.
    """
    found = np.zeros(4 * len(corners), bool)
    a, b = corners.reshape(-1, 2), corners[:, NEXT].reshape(-1, 2)
    side_lines, outside = side_lines.reshape(-1, 3), outside.reshape(-1, 3)
    length = np.linalg.norm(b - a, axis=1)
    d = (b - a) / np.maximum(length, 1e-9)[:, None]  # (4F, 2) along each side
    up = np.flatnonzero(np.abs(d[:, 0]) <= np.sin(np.deg2rad(max_tilt_deg)))
    if not len(up):
        return found.reshape(-1, 4)
    h, w = image_bgr.shape[:2]
    t = np.linspace(reach[0], reach[1], SAMPLES)[None, :] * length[up, None]  # (U, K)
    # (U, 2 ends, K, 2): points past the end b and before the start a
    along = t[..., None] * d[up, None]
    pts = np.stack([b[up, None] + along, a[up, None] - along], axis=1)
    n = side_lines[up, None, None, :2]
    probe = np.stack([pts + OFFSET_PX * n, pts - OFFSET_PX * n])  # (2 out/in, U, 2, K, 2)
    flat = probe.reshape(-1, 2).astype(np.float32)
    col = cv2.remap(image_bgr, flat[:, :1], flat[:, 1:], cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE).reshape(probe.shape[:-1] + (3,))
    out_c, in_c = col[0].astype(np.float64), col[1].astype(np.float64)  # (U, 2, K, 3)
    seen = ((probe >= 0.0) & (probe <= np.array([w - 1.0, h - 1.0]))).all(axis=(0, -1))
    k = seen.sum(axis=2)
    frac = ((np.linalg.norm(out_c - in_c, axis=-1) >= min_step) & seen).sum(axis=2) / \
        np.maximum(k, 1)
    runs = ((frac >= min_frac) & (k >= SAMPLES // 2)).all(axis=1)
    for i in np.flatnonzero(runs):  # rare: the colours' medians (an edge, not texture)
        o, j = outside[up[i]], seen[i]
        med_out, med_in = (np.array([np.median(c[e][j[e]], axis=0) for e in range(2)])
                           for c in (out_c[i], in_c[i]))
        # The typical colours either side differ, the outer one the side's outside colour (a
        # post's), the inner one not (a textured ground passes the test on single points).
        found[up[i]] = bool(((np.linalg.norm(med_out - med_in, axis=1) >= min_step) &
                             (np.linalg.norm(med_out - o, axis=1) <
                              np.linalg.norm(med_in - o, axis=1))).all())
    return found.reshape(-1, 4)


def join_pieces(faces: list['Face'], tol_frac: float, max_aspect: float) -> list['Face']:
    """
    Return ``faces`` with the two pieces of a face that a post splits joined into one.

    A post across the middle of a face leaves two pieces of its colour, at least one cut
    along the post's edge (``Face.cut``), facing each other across the gap: the face's top
    and bottom sides go on straight through the post, so each piece's near corners lie on the
    lines through the two pieces' far corners (within ``tol_frac`` of that line's length). The
    joined face is the whole face: its four corners are the pieces' far ones, all cube
    vertices (each piece alone is a cut face, posed only by extrapolation).
    """
    out = list(faces)
    used: set[int] = set()
    for a, fa in enumerate(faces):
        if fa.cut < 0 or fa.thin or fa.tip or a in used:
            continue
        ca = fa.corners_px.mean(axis=0)
        for b, fb in enumerate(faces):
            if b == a or b in used or fb.thin or fb.tip or fb.colour != fa.colour or \
                    fb.outside >= 0:
                continue
            # b's side facing a: its own cut, else the one a lies farthest beyond
            d = fb.cut if fb.cut >= 0 else int(np.argmax(fb.lines[:, :2] @ ca + fb.lines[:, 2]))
            joined = _joined(fa, fa.cut, fb, d, tol_frac, max_aspect)
            if joined is not None:
                out[a], out[b] = joined, None
                used |= {a, b}
                break
    return [f for f in out if f is not None]


def _joined(fa: 'Face', c: int, fb: 'Face', d: int, tol_frac: float, max_aspect: float
            ) -> 'Face | None':
    """The face of pieces ``fa`` (cut along side ``c``) and ``fb`` (facing it with side ``d``)."""
    pa, pb = fa.corners_px, fb.corners_px
    # a's near corners c, c+1 beyond b's facing side and b's beyond a's cut: a gap between
    for p, line in ((pb[[d, NEXT[d]]], fa.lines[c]), (pa[[c, NEXT[c]]], fb.lines[d])):
        if (p @ line[:2] + line[2] <= 0.0).any():
            return None
    a2, a3, b2, b3 = pa[(c + 2) % 4], pa[(c + 3) % 4], pb[(d + 2) % 4], pb[(d + 3) % 4]
    corners = np.array([a2, a3, b2, b3])
    side = lines.side_lines(corners)
    # A face seen from beside is no wider than tall (a post is narrower than the face): two
    # objects of the colour far apart are no face. Both pieces cut along the post: it is
    # between them (a top it splits is far wider than tall).
    height = max(np.hypot(*(a3 - a2)), np.hypot(*(b3 - b2)))
    if fb.cut < 0 and max(np.hypot(*(b2 - a3)), np.hypot(*(a2 - b3))) > max_aspect * height:
        return None
    # the near corners on the top (a3 .. b2) and bottom (b3 .. a2) lines
    tol = max(2.0, tol_frac * height)
    for line, near in ((side[1], (pa[c], pb[(d + 1) % 4])), (side[3], (pa[(c + 1) % 4], pb[d]))):
        if max(abs(line[:2] @ n + line[2]) for n in near) > tol:
            return None
    if not cv2.isContourConvex(corners.astype(np.float32)):
        return None
    ls = np.array([fa.lines[(c + 2) % 4], side[1], fb.lines[(d + 2) % 4], side[3]])
    sup = np.array([fa.supports[(c + 2) % 4], min(fa.supports[(c + 3) % 4],
                    fb.supports[(d + 1) % 4]), fb.supports[(d + 2) % 4],
                    min(fb.supports[(d + 3) % 4], fa.supports[(c + 1) % 4])])
    return dataclasses.replace(fa, corners_px=corners, lines=ls, supports=sup, cut=-1,
                               runs_on=fa.runs_on and fb.runs_on, seen=(pa, pb))
