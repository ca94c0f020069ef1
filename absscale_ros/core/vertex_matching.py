"""
Target vertex correspondences between two registered keyframes (paper Step 2, eq. 2-7).

The candidates of a vertex in keyframe a are the vertices of keyframe b near its epipolar line
(eq. 2-4). A cube vertex then takes the candidate whose colour window is most similar (eq. 5-7);
a sheet's four corners, detected in a consistent clockwise order, take the cyclic shift of that
order that best fits the epipolar lines.

Neither test can tell apart two cube vertices a few px apart near one epipolar line: a cube edge
seen nearly end-on from a camera moving along it (fresh outdoor 45: corners 4 and 6, 2.5-5 px
apart from 18 m, both within 2.2 px of each other's lines, their windows nearly the same
pixels). The colour score then picks either, and the wrong one triangulates along the
baseline with sub-px residuals (landmarks 1.3 m and 2.1 m off). So a vertex is not matched
while another candidate of the same band lies that close to its match, in either view.
"""
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from absscale_ros.core import twoview

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


@dataclass(frozen=True)
class VertexMatchConfig:
    """Thresholds of vertex matching, and of publishing a vertex landmark."""

    max_epipolar_px: float = 3.0  # distance of a candidate from the epipolar line, px
    window_px: int = 7  # half size of the colour window of eq. 5-7, px
    # Two cube candidates of one vertex closer than this to each other are ambiguous (their
    # colour windows share most pixels): that vertex is not matched in this pair of keyframes.
    ambiguous_px: float = 7.0
    # A vertex landmark is published (target_points) once two of its views are this far apart:
    # the scale node's own min_angle_deg. The outdoor sample's corner seen only from its last two
    # keyframes, 1.27 degrees apart, lay 0.11 m (0.53 % of the extent) off.
    publish_min_angle_deg: float = 3.0

    def __post_init__(self) -> None:
        if self.max_epipolar_px <= 0.0 or self.window_px < 1 or self.ambiguous_px < 0.0 or \
                self.publish_min_angle_deg < 0.0:
            raise ValueError(f'bad vertex matching config {self}')


@dataclass(frozen=True, eq=False)
class Vertices:
    """
    Detected target vertices of one keyframe.

    :param object_ids: (V,) int64 target id of each vertex.
    :param vertex_ids: (V,) int64 vertex id within its target (as the detector numbered it).
    :param points_px: (V, 2) float64 undistorted px.
    :param kinds: (V,) 'sheet' or 'cube' per vertex.
    """

    object_ids: IntArray
    vertex_ids: IntArray
    points_px: FloatArray
    kinds: tuple[str, ...]


def skew(v: FloatArray) -> FloatArray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def fundamental(K: FloatArray, T_a: FloatArray, T_b: FloatArray) -> FloatArray:
    """
    F with ``x_b^T F x_a = 0`` from two registered poses: ``[e']_x P' P^+`` (eq. 4).

    :param T_a: (4, 4) T_world_cam of keyframe a; ``T_b`` of keyframe b.
    """
    P, P2 = twoview.projection(K, T_a), twoview.projection(K, T_b)
    C = np.append(T_a[:3, 3], 1.0)  # centre of camera a: P C = 0 (eq. 2)
    return skew(P2 @ C) @ P2 @ np.linalg.pinv(P)


def epipolar_distances_px(F: FloatArray, pts_a_px: FloatArray, pts_b_px: FloatArray) -> FloatArray:
    """(Na, Nb) distance of each b point from the epipolar line ``l' = F x_a`` (eq. 3-4), px."""
    lines = np.column_stack([pts_a_px, np.ones(len(pts_a_px))]) @ F.T  # (Na, 3)
    hb = np.column_stack([pts_b_px, np.ones(len(pts_b_px))])
    return np.abs(lines @ hb.T) / np.linalg.norm(lines[:, :2], axis=1, keepdims=True)


def _window(image_bgr: npt.NDArray[np.uint8], uv: FloatArray, half: int) -> FloatArray | None:
    u, v = int(round(uv[0])), int(round(uv[1]))
    h, w = image_bgr.shape[:2]
    if not (half <= u < w - half and half <= v < h - half):
        return None
    rgb = image_bgr[v - half:v + half + 1, u - half:u + half + 1, ::-1].astype(np.float64) / 255.0
    return np.concatenate([rgb.mean(axis=2, keepdims=True), rgb], axis=2)  # I, R, G, B


def similarity_score(win_a: FloatArray, win_b: FloatArray) -> float:
    """
    Colour-window similarity of eq. 7, ``Corr / (1 + Col-Diff)``.

    :param win_a: (n, m, 4) intensity and R, G, B in [0, 1]; ``win_b`` the same shape.
    """
    col_diff = float(np.abs(win_a - win_b).sum())  # eq. 5
    corr = float(np.abs(win_a * win_b).sum())  # eq. 6
    return corr / (1.0 + col_diff)


def windows(image_bgr: npt.NDArray[np.uint8], points_px: FloatArray,
            cfg: VertexMatchConfig) -> list[FloatArray | None]:
    """Colour windows (n, n, 4: I, R, G, B in [0, 1]) around each (V, 2) px; None at borders."""
    return [_window(image_bgr, uv, cfg.window_px) for uv in points_px]


def match_cube(va: FloatArray, vb: FloatArray, windows_a: list[FloatArray | None],
               windows_b: list[FloatArray | None], F: FloatArray,
               cfg: VertexMatchConfig) -> list[tuple[int, int]]:
    """
    Match cube vertices: epipolar candidates, best colour-window score, one-to-one (greedy).
    A candidate pair is left out when another vertex of either view near the same epipolar
    line lies within ``cfg.ambiguous_px`` of its own (see the module docstring).

    :param va: (Na, 2) undistorted px in a; ``vb`` (Nb, 2) in b.
    :param windows_a: ``windows`` of a's vertices; ``windows_b`` of b's.
    :returns: (index in a, index in b) pairs.
    """
    band = epipolar_distances_px(F, va, vb) < cfg.max_epipolar_px
    ok = band & ~_ambiguous(band, va, vb, cfg.ambiguous_px)
    scored = []
    for i in range(len(va)):
        wa = windows_a[i]
        for j in np.flatnonzero(ok[i]):
            wb = windows_b[j]
            if wa is not None and wb is not None:
                scored.append((similarity_score(wa, wb), i, int(j)))
    pairs, used_a, used_b = [], set(), set()
    for _, i, j in sorted(scored, reverse=True):
        if i not in used_a and j not in used_b:
            pairs.append((i, j))
            used_a.add(i)
            used_b.add(j)
    return pairs


def _ambiguous(band: npt.NDArray[np.bool_], va: FloatArray, vb: FloatArray,
               gap_px: float) -> npt.NDArray[np.bool_]:
    """
    (Na, Nb) whether pair (i, j) has a rival: another candidate of ``i`` within ``gap_px`` of
    ``vb[j]``, or another vertex of a with ``j`` in its band within ``gap_px`` of ``va[i]``.

    :param band: (Na, Nb) whether b's vertex lies near a's vertex's epipolar line.
    """
    def near(v: FloatArray) -> npt.NDArray[np.int64]:
        d = np.linalg.norm(v[:, None] - v[None], axis=2)
        return ((d < gap_px) & ~np.eye(len(v), dtype=bool)).astype(np.int64)
    b = band.astype(np.int64)
    return (b @ near(vb) > 0) | (near(va) @ b > 0)


def match_sheet(va: FloatArray, vb: FloatArray, F: FloatArray,
                cfg: VertexMatchConfig) -> list[tuple[int, int]]:
    """
    Match the four corners of a sheet, each listed in clockwise order from any corner.

    :returns: the four pairs of the best cyclic shift, or none if a corner is off its line.
    """
    if len(va) != 4 or len(vb) != 4:
        return []
    dist = epipolar_distances_px(F, va, vb)
    shifts = [[dist[i, (i + k) % 4] for i in range(4)] for k in range(4)]
    k = int(np.argmin([sum(s) for s in shifts]))
    if max(shifts[k]) >= cfg.max_epipolar_px:
        return []
    return [(i, (i + k) % 4) for i in range(4)]
