"""
Line helpers shared by the detectors: rough quadrilaterals, Hough voting and corners as line
intersections (the sub-pixel refinement of sides is in ``sides``).

A line is a (3,) float64 array ``(a, b, c)`` with ``a**2 + b**2 == 1`` and ``a*u + b*v + c = 0``
for image points ``(u, v)`` in px (OpenCV convention: pixel i's centre at i). Its normal
``(a, b)`` points out of the region being outlined (the sheet or the cube face).
"""
import math

import cv2
import numpy as np
try:  # numpy's private gufunc behind np.linalg.lstsq (numpy is pinned): a stacked solve
    from numpy.linalg import _umath_linalg
except ImportError:  # another numpy: one lstsq per set, the same solutions
    _umath_linalg = None
import numpy.typing as npt

Array = npt.NDArray[np.float64]


def full_px(p: npt.NDArray, scale: float) -> npt.NDArray:
    """Points in px of a work image ``scale`` times the full one, in full-image px (pixel
    centres map to pixel centres)."""
    return (p + 0.5) / scale - 0.5


def border_gaps(points_px: Array, w: int, h: int) -> Array:
    """
    Return (N, 4) how far points (N, 2) px lie inside the left, top, right and bottom border
    of a ``w`` x ``h`` image (the outer edges of its outer pixels, at -0.5 and ``w`` - 0.5),
    negative beyond it.
    """
    x, y = points_px[:, 0], points_px[:, 1]
    return np.stack([x + 0.5, y + 0.5, w - 0.5 - x, h - 0.5 - y], axis=1)


def line_through(p0: Array, p1: Array, inside: Array) -> Array:
    """Return the line through ``p0``, ``p1`` whose normal points away from ``inside``."""
    # Scalar arithmetic: called thousands of times per frame on single points.
    dx, dy = float(p1[0]) - float(p0[0]), float(p1[1]) - float(p0[1])
    norm = max(math.hypot(dx, dy), 1e-12)
    a, b = dy / norm, -dx / norm
    c = -(a * float(p0[0]) + b * float(p0[1]))
    if a * float(inside[0]) + b * float(inside[1]) + c > 0.0:
        a, b, c = -a, -b, -c
    return np.array([a, b, c])


def side_lines(poly: Array) -> Array:
    """
    Return the (K, 3) lines of a convex polygon's sides, side k from corner k to k + 1, their
    normals pointing out (away from the corners' mean).

    :param poly: (K, 2) corners px, in order around the polygon.
    """
    # Python floats: numpy's mean and roll cost ~40 us on a quad, the lines themselves ~20.
    # (The same sums in the same order as ``poly.mean(axis=0)``: bit for bit.)
    pts = poly.tolist()
    k = len(pts)
    cx, cy = pts[0]
    for x, y in pts[1:]:
        cx, cy = cx + x, cy + y
    centre = (cx / k, cy / k)
    return np.array([line_through(pts[i], pts[(i + 1) % k], centre) for i in range(k)])


def depths_inside(points: Array, side_lines_: Array) -> Array:
    """Return (M, K) how far (px) each of ``points`` (M, 2) lies inside each of the K lines
    ``side_lines_`` (K, 3), normals out as ``side_lines`` gives them (negative: outside)."""
    return -(points @ side_lines_[:, :2].T + side_lines_[:, 2])


def intersect(l1: Array, l2: Array) -> Array | None:
    """Return the (2,) intersection of two lines, or None when they are near parallel."""
    px = l1[1] * l2[2] - l1[2] * l2[1]
    py = l1[2] * l2[0] - l1[0] * l2[2]
    pw = l1[0] * l2[1] - l1[1] * l2[0]
    if abs(pw) < 1e-9 * max(1.0, abs(px), abs(py)):
        return None
    return np.array([px / pw, py / pw])


def nearest_point(lines: Array) -> Array:
    """
    Return the point with the least squared distance to all ``lines`` ((K, 3), K >= 2).

    The paper's Step 1: three cube edges rarely meet at one point, so the vertex is the point
    nearest to all of them (normal equations of sum_k (a_k u + b_k v + c_k)^2).
    """
    A, b = lines[:, :2], -lines[:, 2]
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    return np.asarray(sol, dtype=np.float64)


def nearest_points(groups: list[Array]) -> Array:
    """
    Return (V, 2) ``nearest_point`` of each of V sets of lines ((K_v, 3), K_v >= 2): the same
    least-squares solutions (LAPACK's, as ``np.linalg.lstsq`` calls it), one call per line
    count instead of one per set (``lstsq`` costs ~40 us of checks around a 2x2 solve).
    """
    if _umath_linalg is None:
        return np.array([nearest_point(ls) for ls in groups]).reshape(-1, 2)
    out = np.empty((len(groups), 2))
    by_count: dict[int, list[int]] = {}
    for v, ls in enumerate(groups):
        by_count.setdefault(len(ls), []).append(v)
    for k, at in by_count.items():
        stacked = np.array([groups[v] for v in at], dtype=np.float64)  # (B, k, 3)
        # As ``np.linalg.lstsq`` (numpy 2.4): its rcond default and its gufunc, stacked.
        with np.errstate(invalid='raise', over='ignore', divide='ignore', under='ignore'):
            sol, *_ = _umath_linalg.lstsq(stacked[..., :2], -stacked[..., 2:],
                                          np.finfo(np.float64).eps * max(2, k),
                                          signature='ddd->ddid')
        out[at] = sol[..., 0]
    return out


def rough_polygon(contour: npt.NDArray[np.int32], corners: int,
                  fracs: tuple[float, ...] = (0.01, 0.02, 0.03, 0.05, 0.08)) -> Array | None:
    """
    Return a (corners, 2) polygon approximating a convex-ish contour, or None.

    The convex hull is simplified with a growing tolerance (fractions of its perimeter) until
    ``corners`` vertices remain, so small notches (a pen on the sheet, a blurred corner) do not
    add vertices.
    """
    hull = cv2.convexHull(contour)
    perim = cv2.arcLength(hull, True)
    for frac in fracs:
        approx = cv2.approxPolyDP(hull, frac * perim, True)
        if len(approx) == corners:
            return np.asarray(approx.reshape(corners, 2), dtype=np.float64)
        if len(approx) < corners:
            return None
    return None


def rough_quad(contour: npt.NDArray[np.int32]) -> Array | None:
    """Return a (4, 2) quadrilateral approximating a convex-ish contour, or None."""
    return rough_polygon(contour, 4)


def hough_line(points_px: Array, theta0_rad: float, rho0_px: float, theta_res_deg: float = 2.0,
               span_deg: float = 10.0, rho_res_px: float = 1.0) -> tuple[float, float]:
    """
    Return the (theta, rho) Hough peak of ``points_px`` (N, 2) near a guess.

    Votes ``rho = u cos(theta) + v sin(theta)`` at ``theta_res_deg`` steps (the paper uses 2
    degrees) within ``span_deg`` of the guess; a peak is the best 3-bin-wide rho strip, which
    tolerates the slight curvature lens distortion gives to straight edges.
    """
    thetas = theta0_rad + np.deg2rad(np.arange(-span_deg, span_deg + 1e-9, theta_res_deg))
    rhos = points_px[:, :1] * np.cos(thetas) + points_px[:, 1:2] * np.sin(thetas)
    bins = np.round((rhos - rho0_px) / rho_res_px).astype(np.int64)
    half = int(np.abs(bins).max()) + 2
    width = 2 * half + 1
    # One accumulator (theta rows, rho columns) filled in a single bincount.
    acc = np.bincount((bins + half + width * np.arange(len(thetas))).ravel(),
                      minlength=width * len(thetas)).reshape(len(thetas), width)
    strip = acc[:, :-2] + acc[:, 1:-1] + acc[:, 2:]
    j, k = np.unravel_index(int(np.argmax(strip)), strip.shape)
    return float(thetas[j]), rho0_px + (k + 1 - half) * rho_res_px


def cross3(a: Array, b: Array) -> Array:
    """Return the cross product of two 3-vectors (``np.cross`` is slow on single vectors)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                     a[0] * b[1] - a[1] * b[0]])


def hough_lines(points_px: list[Array], theta0s_rad: Array, rho0s_px: Array,
                theta_res_deg: float = 2.0, span_deg: float = 10.0, rho_res_px: float = 1.0
                ) -> list[tuple[float, float]]:
    """
    Return ``hough_line`` of several point sets (each its own guess), in one accumulator: the
    same peaks as one call per set (a wider rho range adds only empty strips).
    """
    if not points_px:
        return []
    return hough_lines_flat(np.concatenate(points_px),
                            np.repeat(np.arange(len(points_px)), [len(p) for p in points_px]),
                            theta0s_rad, rho0s_px, theta_res_deg, span_deg, rho_res_px)


def hough_lines_flat(pts: Array, sid: npt.NDArray[np.int64], theta0s_rad: Array,
                     rho0s_px: Array, theta_res_deg: float = 2.0, span_deg: float = 10.0,
                     rho_res_px: float = 1.0) -> list[tuple[float, float]]:
    """
    ``hough_lines`` of the point sets given as one (N, 2) array ``pts`` and (N,) ``sid``, the
    set of each point (every set of ``theta0s_rad`` holds a point).
    """
    offs = np.deg2rad(np.arange(-span_deg, span_deg + 1e-9, theta_res_deg))
    thetas = np.asarray(theta0s_rad)[:, None] + offs  # (S, T), as theta0 + offs per set
    rhos = pts[:, :1] * np.cos(thetas)[sid] + pts[:, 1:2] * np.sin(thetas)[sid]
    bins = np.round((rhos - np.asarray(rho0s_px)[sid, None]) / rho_res_px).astype(np.int64)
    n_s = len(thetas)
    halves = np.zeros(n_s, dtype=np.int64)
    np.maximum.at(halves, sid, np.abs(bins).max(axis=1))
    half = int(halves.max()) + 2
    width, n_t = 2 * half + 1, thetas.shape[1]
    # The 3-bin-wide strips voted for directly: a vote in bin a counts in strips a-2, a-1 and a
    # (the same counts as summing a (set, theta, rho) accumulator, without it).
    at = ((sid[:, None] * n_t + np.arange(n_t)) * (width - 2) + bins + half - 2).ravel()
    strip = np.bincount(np.concatenate([at, at + 1, at + 2]),
                        minlength=n_s * n_t * (width - 2)).reshape(n_s, -1)
    j, k = np.divmod(np.argmax(strip, axis=1), width - 2)
    return [(float(thetas[s, j[s]]), float(rho0s_px[s] + (k[s] + 1 - half) * rho_res_px))
            for s in range(n_s)]


def quad_corners(lines: list[Array]) -> Array | None:
    """Return the (4, 2) corners of four cyclically ordered side lines, or None."""
    corners = []
    for i in range(4):
        p = intersect(lines[i - 1], lines[i])
        if p is None:
            return None
        corners.append(p)
    return np.array(corners)


def rectangle_aspect(corners_px: Array, K: Array | None, focal_px: float,
                     centre_px: Array) -> float:
    """
    Return the long/short side ratio of the rectangle whose image is ``corners_px`` (4, 2).

    Zhang and He's whiteboard method: the two vanishing points give the focal length when it
    is unknown (``K`` None), which falls back to ``focal_px`` when the sides are too close to
    parallel to tell; with the intrinsics the homography gives the side ratio.
    """
    # Scalar arithmetic (``_side_directions`` of one quadrilateral): called on every candidate.
    (x0, y0), (x1, y1), (x2, y2), (x3, y3) = (map(float, p) for p in corners_px)
    c03 = (y0 - y2, x2 - x0, x0 * y2 - y0 * x2)  # m0 x m3 (m = corners 0, 1, 3, 2)
    k2 = (c03[0] * x3 + c03[1] * y3 + c03[2]) / (
        (y1 - y2) * x3 + (x2 - x1) * y3 + (x1 * y2 - y1 * x2))
    k3 = (c03[0] * x1 + c03[1] * y1 + c03[2]) / (
        (y3 - y2) * x1 + (x2 - x3) * y1 + (x3 * y2 - y3 * x2))
    n2 = (k2 * x1 - x0, k2 * y1 - y0, k2 - 1.0)
    n3 = (k3 * x3 - x0, k3 * y3 - y0, k3 - 1.0)
    if K is None:
        u0, v0 = float(centre_px[0]), float(centre_px[1])
        f2 = focal_px ** 2
        if abs(n2[2] * n3[2]) > 1e-12:
            est = -((n2[0] * n3[0] - (n2[0] * n3[2] + n2[2] * n3[0]) * u0
                     + n2[2] * n3[2] * u0 ** 2)
                    + (n2[1] * n3[1] - (n2[1] * n3[2] + n2[2] * n3[1]) * v0
                       + n2[2] * n3[2] * v0 ** 2)) / (n2[2] * n3[2])
            if (0.3 * focal_px) ** 2 < est < (3.0 * focal_px) ** 2:
                f2 = est
        K = np.array([[math.sqrt(f2), 0.0, u0], [0.0, math.sqrt(f2), v0], [0.0, 0.0, 1.0]])
    Ki = np.linalg.inv(K).tolist()
    a2 = [r[0] * n2[0] + r[1] * n2[1] + r[2] * n2[2] for r in Ki]
    a3 = [r[0] * n3[0] + r[1] * n3[1] + r[2] * n3[2] for r in Ki]
    ratio = math.sqrt((a2[0] * a2[0] + a2[1] * a2[1] + a2[2] * a2[2])
                      / max(a3[0] * a3[0] + a3[1] * a3[1] + a3[2] * a3[2], 1e-18))
    return max(ratio, 1.0 / max(ratio, 1e-12))


def rectangle_aspects(corners_px: Array, K: Array) -> Array:
    """
    ``rectangle_aspect`` with intrinsics of many quadrilaterals (M, 4, 2) at once: (M,).
    """
    return _aspects_with_K(*_side_directions(corners_px), K)


def rectangle_aspects_each(corners_px: Array, K: Array) -> Array:
    """
    ``rectangle_aspect`` with intrinsics of many quadrilaterals (M, 4, 2) at once: (M,), bit
    for bit its values (its sums written out element by element; ``rectangle_aspects``'
    matrix product rounds differently in the last bits).
    """
    n2, n3 = _side_directions(corners_px)
    Ki = np.linalg.inv(K).tolist()
    a2 = [r[0] * n2[:, 0] + r[1] * n2[:, 1] + r[2] * n2[:, 2] for r in Ki]
    a3 = [r[0] * n3[:, 0] + r[1] * n3[:, 1] + r[2] * n3[:, 2] for r in Ki]
    ratio = np.sqrt((a2[0] * a2[0] + a2[1] * a2[1] + a2[2] * a2[2])
                    / np.maximum(a3[0] * a3[0] + a3[1] * a3[1] + a3[2] * a3[2], 1e-18))
    return np.maximum(ratio, 1.0 / np.maximum(ratio, 1e-12))


def _side_directions(corners_px: Array) -> tuple[Array, Array]:
    """(M, 3) homogeneous images of the two side directions of M quadrilaterals (M, 4, 2)."""
    # m0..m3 = corners 0, 1, 3, 2 with w = 1; cross products written out (np.cross is slow).
    x0, y0 = corners_px[:, 0, 0], corners_px[:, 0, 1]
    x1, y1 = corners_px[:, 1, 0], corners_px[:, 1, 1]
    x2, y2 = corners_px[:, 2, 0], corners_px[:, 2, 1]
    x3, y3 = corners_px[:, 3, 0], corners_px[:, 3, 1]
    c0, c1, c2 = y0 - y2, x2 - x0, x0 * y2 - y0 * x2  # m0 x m3
    k2 = (c0 * x3 + c1 * y3 + c2) / ((y1 - y2) * x3 + (x2 - x1) * y3 + (x1 * y2 - y1 * x2))
    k3 = (c0 * x1 + c1 * y1 + c2) / ((y3 - y2) * x1 + (x2 - x3) * y1 + (x3 * y2 - y3 * x2))
    return (np.stack([k2 * x1 - x0, k2 * y1 - y0, k2 - 1.0], axis=1),
            np.stack([k3 * x3 - x0, k3 * y3 - y0, k3 - 1.0], axis=1))


def _aspects_with_K(n2: Array, n3: Array, K: Array) -> Array:
    """(M,) long/short side ratios from the side directions and the intrinsics."""
    Ki = np.linalg.inv(K)
    a2, a3 = n2 @ Ki.T, n3 @ Ki.T
    ratio = np.sqrt(np.einsum('mi,mi->m', a2, a2) / np.maximum(np.einsum('mi,mi->m', a3, a3),
                                                               1e-18))
    return np.maximum(ratio, 1.0 / np.maximum(ratio, 1e-12))
