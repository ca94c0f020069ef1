"""
Cube assembly: face corners merged into cube vertices, and one detection per cube.

Corners of different faces that meet are one cube vertex: the point nearest (least squares)
to all the edges meeting there, as the paper does when three edges do not meet exactly.
"""
import dataclasses
from typing import Callable, TYPE_CHECKING

import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core import cube_fill, cube_geometry, lines, targets

if TYPE_CHECKING:
    from absscale_ros.core.detect_cube import Face

Array = npt.NDArray[np.float64]
# (colour, outlines (K, 2) px) -> index of the outline that the image's pixels fit best
OutlineFit = Callable[[str, list[Array]], int]
MIN_POSING_ASPECT = 0.35  # a narrower face (seen nearly edge-on) poses the cube poorly
BORDER_PX = 2.0  # a face corner this close to the image border is where the border cuts it


def find(parent: list[int], i: int) -> int:
    """Return the root of ``i`` in a union-find forest (with path halving)."""
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


def cluster_corners(faces: list['Face'], merge_frac: float) -> npt.NDArray[np.int64]:
    """Return a cluster label per face corner (F*4,), merging near corners of other faces."""
    pts = np.concatenate([f.corners_px for f in faces])
    owner = np.repeat(np.arange(len(faces)), 4)
    sides = [np.hypot(*(f.corners_px - f.corners_px[[1, 2, 3, 0]]).T) for f in faces]
    longest = np.array([s.max() for s in sides])
    # (a tip face repeats its seen corner: its shortest side is a real one)
    shortest = np.array([(s[s > 0.0] if f.tip else s).min() for s, f in zip(sides, faces)])
    parent = list(range(len(pts)))
    # A fraction of the longer sides (a narrow face's short side would allow too little), but
    # never so much that both ends of a short side could merge.
    la, sa = longest[owner], shortest[owner]
    tol = np.maximum(3.0, np.minimum(merge_frac * np.minimum(la[:, None], la[None, :]),
                                     0.4 * np.minimum(sa[:, None], sa[None, :])))
    colour = np.array([faces[o].colour for o in owner])
    dist = np.hypot(pts[:, None, 0] - pts[None, :, 0], pts[:, None, 1] - pts[None, :, 1])
    near = (dist < tol) & (colour[:, None] != colour[None, :])  # other faces: other colours
    for i, j in zip(*np.nonzero(np.triu(near, 1))):  # in the order of the pairwise loop
        parent[find(parent, int(i))] = find(parent, int(j))
    return np.array([find(parent, i) for i in range(len(pts))], dtype=np.int64)


def mute_sandwiched(faces: list['Face'], labels: npt.NDArray[np.int64]) -> list['Face']:
    """
    Return ``faces`` with every strip whose far side reaches a corner of another whole face
    made mute (``runs_on``): a face seen edge-on borders the cube's faces on one side only
    (beyond it lie hidden faces or the background), so a strip between two faces (a cube's
    top seen under a box of a cube colour behind it) says nothing about either pose.

    :param labels: (F*4,) cluster label per face corner (``cluster_corners``).
    """
    whole = {int(lab) for f, face in enumerate(faces) if not face.thin
             for lab in labels[4 * f:4 * f + 4]}
    out = []
    for f, face in enumerate(faces):
        lab = labels[4 * f:4 * f + 4]  # strip corners: c0, far0, far1, c1
        far = {int(lab[1]), int(lab[2])} - {int(lab[0]), int(lab[3])}
        if face.thin and not face.runs_on and far & whole:
            face = dataclasses.replace(face, runs_on=True)
        out.append(face)
    return out


def _posing(face: 'Face') -> bool:
    """
    Return True for a face that fixes a pose: whole (not a strip, not cut by the image
    border), and seen at most 70 deg off-axis.
    """
    sides = np.hypot(*(face.corners_px - face.corners_px[[1, 2, 3, 0]]).T)
    return not face.thin and face.cut < 0 and face.outside < 0 and \
        sides.min() >= MIN_POSING_ASPECT * sides.max()


def _explained(faces: list['Face'], vertices: Array, Ks: list[Array], tol_frac: float,
               loose_ramp_px: float, carry_widen: float
               ) -> tuple[npt.NDArray[np.bool_], cube_geometry.Posed | None]:
    """
    Return ``cube_geometry.explained`` of a cube's vertices (V, 2) px by its posing faces:
    whole ones, and cut ones completed from their seen whole side and the two sides leaving
    it (with known intrinsics only) when sharp, or when their sides ramp over at most
    ``loose_ramp_px`` (an extrapolation from smeared sides: asked only when the sharp poses
    keep no vertex, which it would otherwise veto).
    """
    posing = [_posing(f) for f in faces]
    completed = {f: cube_geometry.complete_cut(face.corners_px, face.lines, face.cut, Ks[0])
                 for f, face in enumerate(faces) if face.cut >= 0 and len(Ks) == 1 and
                 not face.tip and (not face.runs_on or face.ramp_px <= loose_ramp_px)}
    completed = {f: c for f, c in completed.items()
                 if c is not None and _posing(dataclasses.replace(faces[f], corners_px=c, cut=-1))}
    posing = [p or f in completed for f, p in enumerate(posing)]
    # A smeared cut face poses nothing, but its seen part still lies where a pose puts it.
    return cube_geometry.explained(vertices, list(np.flatnonzero(posing)),
                                   _completed_strips(faces, completed, carry_widen),
                                   [f.thin for f in faces],
                                   [f.runs_on and f.cut < 0 for f in faces], Ks, tol_frac,
                                   completed)


def _completed_strips(faces: list['Face'], completed: dict[int, Array], carry_widen: float
                      ) -> list[Array]:
    """
    Return the faces' outlines, with each strip along a side of a ``completed`` cut face
    carried on, along its side and its far side, to the corner the completion puts where the
    border or a post cuts that side: seen, the strip ends there too, on no cube vertex (the
    cube posed on the completed face would never agree with it). Not when that widens it to
    over ``carry_widen`` times its widest end seen (0: never): a face seen edge-on keeps its
    width within ~1.5x over its length, so a wedge is no such face (a strip tapering from 25 px
    to 1 beside a box of a face's colour, carried on to 68 px, agreed with that box's pose).
    """
    polys = [f.corners_px for f in faces]
    for f, corners in completed.items():
        cut = faces[f].cut
        for g, strip in enumerate(polys):
            if not faces[g].thin:
                continue
            for end, far, other in ((0, 1, 3), (3, 2, 0)):
                for c in (cut, (cut + 1) % 4):
                    if not np.array_equal(strip[end], faces[f].corners_px[c]):
                        continue
                    along = strip[other] - strip[end]
                    t = (corners[c] - strip[end]) @ along / max(float(along @ along), 1e-12)
                    carried = strip.copy()
                    carried[far] = strip[far] + t * (strip[3 - far] - strip[far])
                    carried[end] = corners[c]
                    widest = max(np.hypot(*(strip[1] - strip[0])),
                                 np.hypot(*(strip[2] - strip[3])))
                    if np.hypot(*(carried[far] - carried[end])) <= carry_widen * widest:
                        strip = carried
            polys[g] = strip
    return polys


def cube_detection(faces: list['Face'], labels: list[npt.NDArray[np.int64]], Ks: list[Array],
                   shape: tuple[int, ...], shape_tol_frac: float, loose_ramp_px: float = 0.0,
                   carry_widen: float = 0.0,
                   outline: list[float | None] | None = None,
                   best_outline: OutlineFit | None = None,
                   fill: cube_fill.FillFn | None = None) -> targets.TargetDetection | None:
    """
    Assemble vertices (least-squares points of meeting edges), ids and edges of a cube.

    A thin face adds its colour to the two corners it shares, not its far corners; a face
    the image border cuts adds its two corners off the border only. Vertices
    that no cube pose explains (``cube_geometry``) and corners where the image border cuts a
    face are left out, and faces left with none of their corners; None when no vertex where
    two colours meet is left. When the sharp poses leave none, cut faces whose sides ramp
    over at most ``loose_ramp_px`` pose the cube too (``_explained``; ``carry_widen``: see
    ``_completed_strips``). Appends to ``outline``
    the area px of the posed cube's outline within the image (``posed_area``) of a detection.
    A strip's ends follow the cube's edges where the believed pose puts them
    (``cube_geometry.complete_strip``), unless ``best_outline`` prefers it as measured. A face
    the pose shows of a colour no face found has is outlined by ``fill`` (``cube_fill``).
    """
    # (nor the two corners where the image border cuts a face: the border's, not the cube's,
    # nor a corner beyond it)
    measured = [(0, 3) if f.thin else [(f.cut + 2) % 4] if f.tip else
                [c for c in range(4) if (f.cut < 0 or (c - f.cut) % 4 > 1) and c != f.outside]
                for f in faces]
    keys = sorted({int(lab[c]) for lab, cs in zip(labels, measured) for c in cs})
    index = {k: i for i, k in enumerate(keys)}
    meeting: list[list[Array]] = [[] for _ in keys]
    masks = np.zeros(len(keys), dtype=np.int64)
    edges = set()
    for face, lab, cs in zip(faces, labels, measured):
        for c in cs:
            v = index[int(lab[c])]
            meeting[v] += [face.lines[c - 1], face.lines[c]]  # the two sides at corner c
            masks[v] |= targets.COLOUR_BITS[face.colour]
            w = index.get(int(lab[(c + 1) % 4]))
            if w is not None and w != v:
                edges.add((min(v, w), max(v, w)))
    vertices = lines.nearest_points([np.array(ls) for ls in meeting])
    h, w = shape[:2]
    ok = (vertices >= BORDER_PX).all(axis=1) & (vertices[:, 0] <= w - 1 - BORDER_PX) & (
        vertices[:, 1] <= h - 1 - BORDER_PX)
    # A corner a face loses to the border or to a post in front hides its colour there: a
    # vertex another face puts at it would go without that colour (a wrong id).
    lost = {int(lab[c]) for f, lab, cs in zip(faces, labels, measured) if not f.thin
            for c in range(4) if c not in cs and not (f.tip and c == (f.cut + 3) % 4)}
    ok &= np.array([k not in lost for k in keys])
    two = np.array([bin(int(m)).count('1') >= 2 for m in masks])  # colours meet there
    keep, proj = _explained(faces, vertices, Ks, shape_tol_frac, 0.0, carry_widen)
    if not (keep & ok & two).any() and any(f.cut >= 0 and f.runs_on and
                                           f.ramp_px <= loose_ramp_px for f in faces):
        keep, proj = _explained(faces, vertices, Ks, shape_tol_frac, loose_ramp_px,
                                carry_widen)
    keep &= ok
    if not (keep & two).any():
        return None
    seen = [any(keep[index[int(lab[c])]] for c in cs) for lab, cs in zip(labels, measured)]
    faces = [f for f, s in zip(faces, seen) if s]
    new = np.cumsum(keep) - 1
    edges = {(int(new[a]), int(new[b])) for a, b in edges if keep[a] and keep[b]}
    vertices, masks = vertices[keep], masks[keep]
    ids = np.zeros(len(vertices), dtype=np.int64)
    centre = vertices.mean(axis=0)
    # Clockwise from the top (image y down) among vertices with the same colour mask.
    ang = np.mod(np.arctan2(vertices[:, 1] - centre[1], vertices[:, 0] - centre[0]) + np.pi / 2,
                 2 * np.pi)
    for m in np.unique(masks):
        same = np.flatnonzero(masks == m)
        for k, v in enumerate(same[np.argsort(ang[same])]):
            ids[v] = targets.cube_vertex_id(int(m), k)
    score = float(np.mean([f.supports.mean() for f in faces]))
    if outline is not None:
        outline.append(None if proj is None else posed_area(proj[0], shape))
    # A face joined across a post in front (``Face.seen``) shows its pieces only.
    polygons = tuple((f.colour, _strip_outline(f, proj, best_outline) if f.thin else
                      f.corners_px) for f in faces if not f.seen) + \
        tuple((f.colour, p) for f in faces for p in f.seen)
    if fill is not None and proj is not None:
        polygons += tuple((colour, p) for colour, face in cube_fill.missing_faces(
            proj[0], list(polygons)) for p in [fill(colour, face)] if p is not None)
    return targets.TargetDetection(
        target_type='cube', name='cube', vertices_px=vertices, vertex_ids=ids,
        edges=np.array(sorted(edges), dtype=np.int64).reshape(-1, 2), polygons=polygons,
        score=score)


def _strip_outline(face: 'Face', proj: cube_geometry.Posed | None,
                   best_outline: OutlineFit | None) -> Array:
    """
    Return the outline of a strip (a face seen edge-on): its far corners where the believed
    pose ``proj`` puts them, or as measured along the shared side's normal when
    ``best_outline`` finds that the image fits better (a face seen nearly square-on poses
    the depth of its neighbours loosely: a top a few px wide was drawn up to ~15 px long at
    each end, and wider).
    """
    if proj is None:
        return face.corners_px
    posed = cube_geometry.complete_strip(*proj, face.corners_px)
    if best_outline is None or posed is face.corners_px:
        return posed
    return [posed, face.corners_px][best_outline(face.colour, [posed, face.corners_px])]


def posed_area(proj: Array, shape: tuple[int, ...]) -> float:
    """
    Return the area px of the outline of the projected cube ``proj`` (8, 2) px within the
    image: the cube's visible area, posts in front aside. Unlike the sum of its face
    polygons, no box of a face's colour behind the cube (joined with that face, or taken for
    a face seen edge-on) adds to it: its corners are where no pose puts the cube's.
    """
    h, w = shape[:2]
    image = np.array([[0, 0], [w, 0], [w, h], [0, h]], np.float32)
    try:
        return float(cv2.intersectConvexConvex(cv2.convexHull(proj.astype(np.float32)),
                                               image)[0])
    except cv2.error:  # a degenerate outline
        return 0.0
