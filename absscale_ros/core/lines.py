"""
Line helpers shared by the detectors: rough quadrilaterals, Hough voting, edge refinement on
image profiles, robust line fits and corners as line intersections.

A line is a (3,) float64 array ``(a, b, c)`` with ``a**2 + b**2 == 1`` and ``a*u + b*v + c = 0``
for image points ``(u, v)`` in px (OpenCV convention: pixel i's centre at i). Its normal
``(a, b)`` points out of the region being outlined (the sheet or the cube face).
"""
import cv2
import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.float64]


def line_through(p0: Array, p1: Array, inside: Array) -> Array:
    """Return the line through ``p0``, ``p1`` whose normal points away from ``inside``."""
    d = p1 - p0
    n = np.array([d[1], -d[0]]) / max(float(np.hypot(*d)), 1e-12)
    c = -float(n @ p0)
    if n @ inside + c > 0.0:
        n, c = -n, -c
    return np.array([n[0], n[1], c])


def intersect(l1: Array, l2: Array) -> Array | None:
    """Return the (2,) intersection of two lines, or None when they are near parallel."""
    p = np.cross(l1, l2)
    if abs(p[2]) < 1e-9 * max(1.0, float(np.abs(p[:2]).max())):
        return None
    return p[:2] / p[2]


def nearest_point(lines: Array) -> Array:
    """
    Return the point with the least squared distance to all ``lines`` ((K, 3), K >= 2).

    The paper's Step 1: three cube edges rarely meet at one point, so the vertex is the point
    nearest to all of them (normal equations of sum_k (a_k u + b_k v + c_k)^2).
    """
    A, b = lines[:, :2], -lines[:, 2]
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    return np.asarray(sol, dtype=np.float64)


def rough_quad(contour: npt.NDArray[np.int32]) -> Array | None:
    """
    Return a (4, 2) quadrilateral approximating a convex-ish contour, or None.

    The convex hull is simplified with a growing tolerance until four vertices remain, so
    small notches (a pen on the sheet, a blurred corner) do not add vertices.
    """
    hull = cv2.convexHull(contour)
    perim = cv2.arcLength(hull, True)
    for frac in (0.01, 0.02, 0.03, 0.05, 0.08):
        approx = cv2.approxPolyDP(hull, frac * perim, True)
        if len(approx) == 4:
            return np.asarray(approx.reshape(4, 2), dtype=np.float64)
        if len(approx) < 4:
            return None
    return None


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


def fit_line(points_px: Array, weights: Array, outward: Array, iters: int = 3,
             scale_px: float = 1.0) -> Array:
    """
    Return the robust total-least-squares line of weighted points (N, 2).

    Iteratively reweighted with Tukey's biweight (cut-off 4.685 * ``scale_px``) so stray edge
    samples (text, a cable, another page) do not pull the line. ``outward`` orients the normal.
    """
    w = weights.astype(np.float64).copy()
    line = np.zeros(3)
    for _ in range(iters):
        sw = float(w.sum())
        if sw <= 0.0:
            break
        mean = (w[:, None] * points_px).sum(0) / sw
        d = points_px - mean
        cxx, cyy = float(w @ (d[:, 0] ** 2)), float(w @ (d[:, 1] ** 2))
        cxy = float(w @ (d[:, 0] * d[:, 1]))
        # Direction of largest spread of the 2x2 scatter matrix in closed form; the normal
        # is perpendicular to it.
        phi = 0.5 * np.arctan2(2.0 * cxy, cxx - cyy)
        n = np.array([-np.sin(phi), np.cos(phi)])
        if n @ outward < 0.0:
            n = -n
        line = np.array([n[0], n[1], -float(n @ mean)])
        r = (d @ n) / (4.685 * scale_px)
        w = weights * np.where(np.abs(r) < 1.0, (1.0 - r ** 2) ** 2, 0.0)
    return line


def edge_points(image: npt.NDArray[np.float32], p0: Array, p1: Array, normal: Array,
                band_px: float, n_samples: int, margin: float = 0.12,
                step_px: float = 0.5) -> tuple[Array, Array]:
    """
    Return the strongest inside-bright to outside-dark edge along normals of a segment.

    Samples ``n_samples`` profiles across the segment ``p0``-``p1`` (leaving ``margin`` of its
    length at both ends, where the neighbouring side interferes), each from ``-band_px`` to
    ``+band_px`` along ``normal`` (pointing outside). The edge on a profile is the steepest
    descent, located to sub-pixel by a parabola through the derivative's peak.

    :param image: (H, W) float32 intensity (or soft mask), brighter inside.
    :returns: ((K, 2) edge points px, (K,) edge strengths), K <= n_samples.
    """
    ts = np.linspace(margin, 1.0 - margin, n_samples)
    centres = p0[None, :] + ts[:, None] * (p1 - p0)[None, :]
    offs = np.arange(-band_px, band_px + 1e-9, step_px)
    xy = centres[:, None, :] + offs[None, :, None] * normal[None, None, :]
    prof = cv2.remap(image, xy[..., 0].astype(np.float32), xy[..., 1].astype(np.float32),
                     cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    drop = prof[:, :-2] - prof[:, 2:]  # central difference, positive where it gets darker
    k = np.argmax(drop, axis=1)
    rows = np.arange(len(k))
    peak = drop[rows, k]
    left = drop[rows, np.maximum(k - 1, 0)]
    right = drop[rows, np.minimum(k + 1, drop.shape[1] - 1)]
    den = left - 2.0 * peak + right
    sub = np.where(np.abs(den) > 1e-9, 0.5 * (left - right) / np.where(den == 0, 1, den), 0.0)
    sub = np.clip(sub, -0.5, 0.5)
    off = offs[1:-1][k] + sub * step_px
    ok = (peak > 0.0) & (k > 0) & (k < drop.shape[1] - 1)
    pts = centres + off[:, None] * normal[None, :]
    return pts[ok], peak[ok]


def refine_side(image: npt.NDArray[np.float32], line: Array, p0: Array, p1: Array,
                bands_px: tuple[float, ...], n_samples: int,
                min_rel_strength: float = 0.3) -> tuple[Array, float]:
    """
    Refine one side of an outline on image gradients, coarse band to fine band.

    :returns: (refined line, support) where support is the fraction of profiles whose edge
        is at least ``min_rel_strength`` of the median edge strength and near the final line.
    """
    support = 0.0
    for band in bands_px:
        q0 = p0 - (line[:2] @ p0 + line[2]) * line[:2]  # project the ends onto the line
        q1 = p1 - (line[:2] @ p1 + line[2]) * line[:2]
        pts, strength = edge_points(image, q0, q1, line[:2], band, n_samples)
        if len(pts) < 3:
            return line, 0.0
        keep = strength >= min_rel_strength * float(np.sort(strength)[len(strength) // 2])
        if keep.sum() < 3:
            return line, 0.0
        line = fit_line(pts[keep], strength[keep], line[:2], scale_px=max(0.5, band / 4.0))
        # Near the line: within 1 px, or 0.5% of the side for sheets that bend a little.
        tol = max(1.0, 0.005 * float(np.hypot(*(p1 - p0))))
        near = np.abs(pts[keep] @ line[:2] + line[2]) < tol
        support = float(near.sum()) / n_samples
    return line, support


def quad_corners(lines: list[Array]) -> Array | None:
    """Return the (4, 2) corners of four cyclically ordered side lines, or None."""
    corners = []
    for i in range(4):
        p = intersect(lines[i - 1], lines[i])
        if p is None:
            return None
        corners.append(p)
    return np.array(corners)


def side_projection(image_f32: npt.NDArray[np.float32], line: Array, p0: Array, p1: Array,
                    offset_px: float = 4.0) -> tuple[npt.NDArray[np.float32], float]:
    """
    Return a multi-channel image projected on the colour step across one side, and the step.

    Colours are sampled ``offset_px`` inside and outside the side's middle part; projecting on
    their difference gives a scalar image where the side is a bright-to-dark step at its true
    place (mixed pixels on the outline are linear blends of the two colours, so the 50% point
    of the step is the edge, unlike a thresholded colour mask).

    :param image_f32: (H, W, C) float32 image.
    :returns: ((H, W) float32 projection, colour step norm).
    """
    q0 = p0 - (line[:2] @ p0 + line[2]) * line[:2]  # the side's ends, on the line
    q1 = p1 - (line[:2] @ p1 + line[2]) * line[:2]
    ts = np.linspace(0.2, 0.8, 16)
    centres = q0[None, :] + ts[:, None] * (q1 - q0)[None, :]
    samples = []
    for off in (-offset_px, offset_px):
        xy = (centres + off * line[:2]).astype(np.float32)
        samples.append(cv2.remap(image_f32, xy[:, 0:1], xy[:, 1:2], cv2.INTER_LINEAR,
                                 borderMode=cv2.BORDER_REPLICATE).reshape(len(ts), -1))
    med = np.sort(np.stack(samples), axis=1)[:, len(ts) // 2]  # per-channel medians
    diff = med[0] - med[1]
    step = float(np.linalg.norm(diff))
    proj = image_f32 @ (diff / max(step, 1e-9)).astype(np.float32)
    return cv2.GaussianBlur(proj, (0, 0), 1.0), step
