"""
Cube face sides that are an occluder's edge.

A post in front of the cube cuts a face along the post's edge: that side is straight and the
face stays a quadrilateral, so it looks like a square seen obliquely, and its two corners on
the post are no cube vertices (tens of px from the hidden ones). What tells the post's edge
from a cube edge is that it runs on past both ends of the side, with the post's colour on
the outside, where a cube edge stops at a vertex: past one end at least lie the ground or
another face on both sides of its line. Such a side is treated as the image border's cut
(``Face.cut``): its corners are left out, and the face poses the cube only completed from
its other sides (``cube_geometry.complete_cut``).
"""
import cv2
import numpy as np
import numpy.typing as npt

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
    found = np.zeros(4, bool)
    a, b = corners, corners[NEXT]
    length = np.linalg.norm(b - a, axis=1)
    d = (b - a) / np.maximum(length, 1e-9)[:, None]  # (4, 2) along each side
    up = np.flatnonzero(np.abs(d[:, 0]) <= np.sin(np.deg2rad(max_tilt_deg)))
    if not len(up):
        return found
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
    return found
