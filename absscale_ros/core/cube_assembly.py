"""
Cube assembly: face corners merged into cube vertices, and one detection per cube.

Corners of different faces that meet are one cube vertex: the point nearest (least squares)
to all the edges meeting there, as the paper does when three edges do not meet exactly.
"""
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from absscale_ros.core import lines, targets

if TYPE_CHECKING:
    from absscale_ros.core.detect_cube import Face

Array = npt.NDArray[np.float64]


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
    side = np.array([np.hypot(*(f.corners_px - np.roll(f.corners_px, -1, 0)).T).min()
                     for f in faces])
    parent = list(range(len(pts)))
    for i in range(len(pts)):
        for j in range(i + 1, len(pts)):
            if owner[i] == owner[j] or faces[owner[i]].colour == faces[owner[j]].colour:
                continue
            tol = max(3.0, merge_frac * min(side[owner[i]], side[owner[j]]))
            if np.hypot(*(pts[i] - pts[j])) < tol:
                parent[find(parent, i)] = find(parent, j)
    return np.array([find(parent, i) for i in range(len(pts))], dtype=np.int64)


def cube_detection(faces: list['Face'], labels: list[npt.NDArray[np.int64]]
                   ) -> targets.TargetDetection:
    """
    Assemble vertices (least-squares points of meeting edges), ids and edges of a cube.

    A thin face adds its colour to the two corners it shares, not its far corners.
    """
    measured = [(0, 3) if f.thin else range(4) for f in faces]
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
    vertices = np.array([lines.nearest_point(np.array(ls)) for ls in meeting])
    ids = np.zeros(len(keys), dtype=np.int64)
    centre = vertices.mean(axis=0)
    # Clockwise from the top (image y down) among vertices with the same colour mask.
    ang = np.mod(np.arctan2(vertices[:, 1] - centre[1], vertices[:, 0] - centre[0]) + np.pi / 2,
                 2 * np.pi)
    for m in np.unique(masks):
        same = np.flatnonzero(masks == m)
        for k, v in enumerate(same[np.argsort(ang[same])]):
            ids[v] = targets.cube_vertex_id(int(m), k)
    score = float(np.mean([f.supports.mean() for f in faces]))
    polygons = tuple((f.colour, f.corners_px) for f in faces)
    return targets.TargetDetection(
        target_type='cube', name='cube', vertices_px=vertices, vertex_ids=ids,
        edges=np.array(sorted(edges), dtype=np.int64).reshape(-1, 2), polygons=polygons,
        score=score)
