"""
A cube face the last frames confirmed: one whole face seen again where the cube was.

A frame can show the cube's one face sharply while nothing else confirms it: its neighbour is
a strip muted by a box of its own colour behind it, or joined with such a box, or cut by a
post. One face poses nothing believable alone (a face a post cuts along its edge looks like
a square seen at an angle), so the frame reports no cube. But the cube detected a few frames
earlier is the same cube: a whole face of the same colour, of the same shape (a
similarity of that face's corners, the frame-to-frame motion) and close to where that face
was, is that face again, and its corners are the vertices that face's corners were, with
their ids (which colours meet there, known from that frame). A post moving over a corner or a
box joined to a side changes the face's shape, and a face one frame found no vertex at keeps
none: only corners the cube then confirmed are reported.

A face a post in front (or the image border) cuts along one side shows its other sides whole:
the side opposite the cut, its two corners, and the two sides leaving them towards the cut
(``held_cut_face``). Mapped onto those two corners by a similarity, that face's other two
corners (hidden now) must lie on the two sides leaving them, on past the cut, as the cube
seen a frame earlier is moved: a box's face cut by a post keeps no such corners. Only the two
seen corners are reported (the cut's own corners are the post's).
"""
from typing import TYPE_CHECKING

import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core import targets
from absscale_ros.core.cube_assembly import BORDER_PX

if TYPE_CHECKING:
    from absscale_ros.core.detect_cube import CubeConfig

Array = npt.NDArray[np.float64]


def similarity_residual(src: Array, dst: Array) -> float:
    """Return the largest distance px of ``dst`` (N, 2) from ``src`` (N, 2) mapped by the
    similarity (rotation, uniform scale, shift) that fits them best (least squares)."""
    s, d = src - src.mean(axis=0), dst - dst.mean(axis=0)
    zs, zd = s[:, 0] + 1j * s[:, 1], d[:, 0] + 1j * d[:, 1]
    a = (np.conj(zs) @ zd) / max(float(np.real(np.conj(zs) @ zs)), 1e-12)
    return float(np.abs(a * zs - zd).max())


def held_face(colour: str, corners_px: Array, last: targets.TargetDetection, age: int,
              shape: tuple[int, ...], cfg: 'CubeConfig', moved: int = 0
              ) -> targets.TargetDetection | None:
    """
    Return a cube detection of one whole face (colour, (4, 2) corners px) when ``last`` (the
    cube detected ``age`` frames ago, or a face of it held since, in the frame before) had a
    face of that colour this face moved from (see the module docstring), with the vertices
    that face's corners were (not those on the border of an image of ``shape``, as
    ``cube_assembly``); else None. ``cfg``: its ``hold_*`` tolerances; ``moved``: the frames
    since ``last`` (the shift allowed; 0: ``age``).
    """
    if not 0 < age <= cfg.hold_frames:
        return None
    moved = moved or age
    side = float(np.hypot(*(corners_px - np.roll(corners_px, -1, axis=0)).T).max())
    area = abs(cv2.contourArea(corners_px.astype(np.float32)))
    best: tuple[float, Array] | None = None  # (corners' spread px, that face's corners)
    turn = np.sign(cv2.contourArea(corners_px.astype(np.float32), oriented=True))
    for c, poly in last.polygons:
        if c != colour or len(poly) != 4:
            continue
        then = np.asarray(poly, np.float64)
        ratio = area / max(abs(cv2.contourArea(then.astype(np.float32))), 1e-9)
        shift = corners_px.mean(axis=0) - then.mean(axis=0)
        if not (1.0 / cfg.hold_scale_change ** 2 <= ratio <= cfg.hold_scale_change ** 2) or \
                float(np.hypot(*shift)) > cfg.hold_shift_frac * side + cfg.hold_shift_px * moved:
            continue
        if np.sign(cv2.contourArea(then.astype(np.float32), oriented=True)) != turn:
            then = then[::-1]  # listed the other way round: never a mirror image
        # Corner to corner as the face moved, not turned: a rectangle matches itself turned
        # half way round as well as unturned.
        spread = [float(np.abs(np.roll(then, -k, axis=0) + shift - corners_px).max())
                  for k in range(4)]
        k = int(np.argmin(spread))
        if best is None or spread[k] < best[0]:
            best = spread[k], np.roll(then, -k, axis=0)
    if best is None or similarity_residual(best[1], corners_px) > max(
            cfg.hold_shape_px, cfg.hold_shape_frac * side):
        return None
    return _held_detection(colour, corners_px, best[1], np.ones(4, bool), last, shape, cfg)


def held_cut_face(colour: str, corners_px: Array, cut: int, last: targets.TargetDetection,
                  age: int, shape: tuple[int, ...], cfg: 'CubeConfig', moved: int = 0
                  ) -> targets.TargetDetection | None:
    """
    Return ``held_face`` of a face cut along side ``cut`` (its corners ``cut`` and ``cut +
    1`` the cut's, not the face's; see the module docstring): its two seen corners with the
    ids of the vertices they were, or None.
    """
    if not 0 < age <= cfg.hold_frames:
        return None
    a, b = (cut + 2) % 4, (cut + 3) % 4  # the seen corners; side a -> b is whole
    # (toward the cut from a and from b: the sides the hidden corners lie on)
    ends = {a: corners_px[(cut + 1) % 4], b: corners_px[cut]}
    seen = corners_px[[a, b]]
    whole = float(np.hypot(*(seen[1] - seen[0])))
    turn = np.sign(cv2.contourArea(corners_px.astype(np.float32), oriented=True))
    best: tuple[float, Array] | None = None  # (hidden corners' distance px, that face's corners)
    for c, poly in last.polygons:
        if c != colour or len(poly) != 4:
            continue
        then = np.asarray(poly, np.float64)
        if np.sign(cv2.contourArea(then.astype(np.float32), oriented=True)) != turn:
            then = then[::-1]
        for k in range(4):
            rolled = np.roll(then, -k, axis=0)
            off = _cut_fit(rolled, seen, ends, a, b, moved or age, cfg)
            if off is not None and (best is None or off < best[0]):
                best = off, rolled
    if best is None or best[0] > max(cfg.hold_shape_px, cfg.hold_shape_frac * whole):
        return None
    return _held_detection(colour, corners_px, best[1], np.isin(np.arange(4), [a, b]), last,
                           shape, cfg)


def _cut_fit(then: Array, seen: Array, ends: dict[int, Array], a: int, b: int, moved: int,
             cfg: 'CubeConfig') -> float | None:
    """
    Return how far px the corners ``then`` (4, 2) of a face, mapped by the similarity that
    takes its corners ``a``, ``b`` onto the ``seen`` (2, 2) corners of a cut face, put its
    other two corners off the lines from ``a`` and ``b`` through the cut's corners ``ends``
    (the larger), or None when that similarity scales, turns or shifts the face by more than
    a face moves in ``moved`` frames, or the cut's corners lie beyond those hidden corners.
    """
    src, dst = then[[a, b]], seen
    zs = complex(*(src[1] - src[0]))
    zd = complex(*(dst[1] - dst[0]))
    if abs(zs) < 1e-9:
        return None
    m = zd / zs  # the similarity: z -> m (z - src0) + dst0
    side = float(np.hypot(*(then - np.roll(then, -1, axis=0)).T).max())
    shift = float(np.hypot(*(dst.mean(axis=0) - src.mean(axis=0))))
    if not 1.0 / cfg.hold_scale_change <= abs(m) <= cfg.hold_scale_change or \
            shift > cfg.hold_shift_frac * side + cfg.hold_shift_px * moved:
        return None
    worst = 0.0
    for near, far in ((a, (a + 3) % 4), (b, (b + 1) % 4)):
        z = m * complex(*(then[far] - src[0])) + complex(*dst[0])
        hidden = np.array([z.real, z.imag])
        start = dst[0] if near == a else dst[1]
        along, to_end = hidden - start, ends[near] - start
        length = float(np.hypot(*along))
        if length < 1e-9:
            return None
        u = along / length
        reach = float(to_end @ u)
        if reach <= 0.0 or reach > length + cfg.hold_shape_px:
            return None  # the seen part runs the other way, or on past the face
        # the hidden corner's distance from the seen side's line
        worst = max(worst, abs(float(to_end[0] * along[1] - to_end[1] * along[0]))
                    / float(np.hypot(*to_end)))
    return worst


def _held_detection(colour: str, corners_px: Array, then: Array, seen: npt.NDArray[np.bool_],
                    last: targets.TargetDetection, shape: tuple[int, ...], cfg: 'CubeConfig'
                    ) -> targets.TargetDetection | None:
    """
    Return the detection of a held face: those of its ``seen`` corners ``corners_px`` (4, 2)
    whose corners ``then`` (4, 2) were vertices of ``last`` of this face's colour, with
    their ids (not those on the image border), or None when none was.
    """
    # The corners that were vertices of the cube that frame, with their ids.
    dist = np.hypot(*(then[:, None, :] - last.vertices_px[None, :, :]).transpose(2, 0, 1))
    nearest = dist.argmin(axis=1)
    was = (dist[np.arange(4), nearest] <= cfg.hold_vertex_px) & seen
    bit = targets.COLOUR_BITS[colour]
    was &= (last.vertex_ids[nearest] & bit) > 0  # a vertex of this face: its colour meets there
    h, w = shape[:2]
    was &= (corners_px >= BORDER_PX).all(axis=1) & (corners_px[:, 0] <= w - 1 - BORDER_PX) & (
        corners_px[:, 1] <= h - 1 - BORDER_PX)
    if not was.any() or len(set(nearest[was])) < int(was.sum()):
        return None
    kept = np.flatnonzero(was)
    index = {int(c): i for i, c in enumerate(kept)}
    edges = sorted((min(index[a], index[b]), max(index[a], index[b]))
                   for a in kept for b in [(a + 1) % 4] if b in index)
    return targets.TargetDetection(
        target_type='cube', name='cube', vertices_px=corners_px[kept].astype(np.float64),
        vertex_ids=last.vertex_ids[nearest[kept]].astype(np.int64),
        edges=np.array(edges, dtype=np.int64).reshape(-1, 2),
        polygons=((colour, corners_px.astype(np.float64)),), score=last.score,
        vertex_scores=np.full(len(kept), targets.HELD_SCORE))  # reported, kept out of the map
