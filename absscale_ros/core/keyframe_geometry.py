"""
Two-view test of keyframe selection (is there a usable baseline?) and its image cues.

Pure rotation and tiny baselines are told apart from real translation with Torr's GRIC
(Geometric Robust Information Criterion, Torr 1998; used for keyframes by Rashidi et al. 2013):
the essential matrix (5 parameters, a 3-dimensional manifold in the 4-D space of point pairs)
competes with a pure rotation (3 parameters, a 2-dimensional manifold). Calibrated models are
used rather than F against H so that a translating camera over a planar floor is not mistaken
for a rotating one: a plane fits a homography, but not a pure rotation.
"""
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core.types import CameraModel

FloatArray = npt.NDArray[np.float64]
_R_DATA = 4.0  # dimension of one observation (two 2-D points)
_LAMBDA3 = 2.0  # robust cap of the squared residual, in sigma^2 per missing dimension
MIN_ANGLE_DEG = 0.5  # triangulation angle of the points the median depth is taken over


@dataclass(frozen=True)
class Motion:
    """
    What two views of tracked points say about the camera motion between them.

    :param inliers: number of point pairs consistent with the essential matrix.
    :param gric_e: GRIC of the essential-matrix model (lower is better).
    :param gric_rot: GRIC of the pure-rotation model.
    :param parallax: median residual of the pure-rotation fit, normalised units (times the
        focal length: px): the parallax that no rotation explains.
    :param degenerate: True when a pure rotation explains the pairs as well (no baseline).
    :param baseline_ratio: baseline / median depth of the triangulated inliers in view 0
        (scale-free); NaN when degenerate or too few points triangulate.
    :param depths: (N,) depth in view 0 of each input pair in units of the baseline, NaN
        where it is not one of the points ``baseline_ratio`` is the median over (None when
        degenerate).
    :param rotation: (3, 3) R_1_0 (None when degenerate).
    :param direction: (3,) unit translation, view 1 from view 0 (None when degenerate).
    """

    inliers: int
    gric_e: float
    gric_rot: float
    parallax: float
    degenerate: bool
    baseline_ratio: float
    depths: FloatArray | None = None
    rotation: FloatArray | None = None
    direction: FloatArray | None = None


def gric(residuals_sq: FloatArray, sigma_sq: float, manifold_dim: int, params: int) -> float:
    """
    Return Torr's GRIC score of one model.

    :param residuals_sq: (N,) squared residuals, same unit as ``sigma_sq``.
    :param manifold_dim: dimension of the model's manifold (E: 3, rotation: 2).
    :param params: number of model parameters (E: 5, rotation: 3).
    """
    n = residuals_sq.size
    rho = np.minimum(residuals_sq / sigma_sq, _LAMBDA3 * (_R_DATA - manifold_dim))
    return float(rho.sum() + np.log(_R_DATA) * manifold_dim * n + np.log(_R_DATA * n) * params)


def _bearings(xy: FloatArray) -> FloatArray:
    rays = np.hstack([xy, np.ones((len(xy), 1))])
    return rays / np.linalg.norm(rays, axis=1, keepdims=True)


def _kabsch(b0: FloatArray, b1: FloatArray) -> FloatArray:
    u, _, vt = np.linalg.svd(b1.T @ b0)
    return u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt


def rotation_fit(xy0: FloatArray, xy1: FloatArray,
                 iterations: int = 3) -> tuple[FloatArray, FloatArray]:
    """
    Fit the rotation that best maps view-0 rays onto view-1 rays, robustly.

    Kabsch on unit bearings, refitted on the pairs within twice the median residual: a few
    corners sliding along an occluding edge must not spoil the fit of a pure rotation.

    :param xy0: (N, 2) normalised undistorted image points of view 0 (x/z, y/z).
    :param xy1: (N, 2) the same points in view 1.
    :returns: R_1_0 (3, 3) and (N,) squared transfer residuals, normalised units.
    """
    b0, b1 = _bearings(xy0), _bearings(xy1)
    keep = np.ones(len(b0), bool)
    for _ in range(iterations):
        R = _kabsch(b0[keep], b1[keep])
        p = b0 @ R.T
        with np.errstate(divide='ignore', invalid='ignore'):
            proj = p[:, :2] / p[:, 2:3]
        res = np.where(p[:, 2:3] > 1e-6, proj - xy1, 1e3)
        res_sq = np.sum(res * res, axis=1)
        nxt = res_sq <= 4.0 * np.median(res_sq)
        if np.count_nonzero(nxt) < 3:
            break
        keep = nxt
    return R, res_sq


def sampson_sq(E: FloatArray, xy0: FloatArray, xy1: FloatArray) -> FloatArray:
    """(N,) squared Sampson distances of the pairs to ``E`` (``x1^T E x0 = 0``), normalised."""
    x0 = np.hstack([xy0, np.ones((len(xy0), 1))])
    x1 = np.hstack([xy1, np.ones((len(xy1), 1))])
    Ex0, Etx1 = x0 @ E.T, x1 @ E
    num = np.einsum('ij,ij->i', x1, Ex0) ** 2
    den = Ex0[:, 0] ** 2 + Ex0[:, 1] ** 2 + Etx1[:, 0] ** 2 + Etx1[:, 1] ** 2
    return num / np.maximum(den, 1e-18)


def baseline_ratio(R: FloatArray, t: FloatArray, xy0: FloatArray, xy1: FloatArray) -> float:
    """
    Baseline over median depth from triangulating the pairs with a unit baseline.

    :param R: (3, 3) R_1_0; :param t: (3,) unit translation, view 1 from view 0.
    :returns: 1 / median positive depth in view 0, or NaN when fewer than 5 points lie in front.
    """
    z0 = unit_baseline_depths(R, t, xy0, xy1)
    return float(1.0 / np.nanmedian(z0)) if np.any(np.isfinite(z0)) else float('nan')


def unit_baseline_depths(R: FloatArray, t: FloatArray, xy0: FloatArray,
                         xy1: FloatArray) -> FloatArray:
    """
    Depths in view 0 of the pairs triangulated with a unit baseline.

    :param R: (3, 3) R_1_0; :param t: (3,) unit translation, view 1 from view 0.
    :returns: (N,) depths in baselines; NaN behind either camera, under a tiny triangulation
        angle (unless too few others remain), and everywhere when fewer than 5 remain.
    """
    P0 = np.hstack([np.eye(3), np.zeros((3, 1))])
    P1 = np.hstack([R, t.reshape(3, 1)])
    X = cv2.triangulatePoints(P0, P1, xy0.T.astype(np.float64), xy1.T.astype(np.float64))
    with np.errstate(divide='ignore', invalid='ignore'):
        z0 = X[2] / X[3]
        z1 = (R[2] @ X[:3] + t[2] * X[3]) / X[3]
    good = np.isfinite(z0) & (z0 > 0.0) & (z1 > 0.0)
    # Points seen under a tiny angle (near the epipole of a forward walk) get wild depths that
    # drag the median far; leave them out unless too few others remain.
    with np.errstate(divide='ignore', invalid='ignore'):
        P = (X[:3] / X[3]).T
    c1 = -R.T @ t
    cos = np.einsum('ij,ij->i', P, P - c1) / (np.linalg.norm(P, axis=1)
                                              * np.linalg.norm(P - c1, axis=1))
    steep = good & (cos < np.cos(np.deg2rad(MIN_ANGLE_DEG)))
    if np.count_nonzero(steep) >= 5 and np.count_nonzero(steep) >= 0.3 * np.count_nonzero(good):
        good = steep
    if np.count_nonzero(good) < 5:
        good[:] = False
    return np.where(good, z0, np.nan)


def analyse(xy0: FloatArray, xy1: FloatArray, sigma_norm: float, min_inliers: int,
            min_parallax: float = 0.0, min_inlier_ratio: float = 0.5,
            rot_sq: FloatArray | None = None) -> Motion:
    """
    Fit E and a pure rotation to the pairs, pick by GRIC, and measure the baseline ratio.

    :param xy0: (N, 2) normalised undistorted points in view 0.
    :param xy1: (N, 2) matching points in view 1.
    :param sigma_norm: image noise in normalised units (pixel sigma / focal length).
    :param min_inliers: fewer E inliers than this is degenerate (not enough evidence).
    :param min_parallax: less parallax than this (normalised units) is degenerate: a tiny
        baseline, or KLT drift over a long rotation that GRIC alone may take for one.
    :param min_inlier_ratio: a smaller fraction of E inliers is degenerate (no consistent
        motion: tracks gone wrong).
    :param rot_sq: (N,) residuals of ``rotation_fit(xy0, xy1)`` if the caller has them.

    Both models are scored on every pair (GRIC caps the outliers' cost), not on the E
    inliers only: that would favour E by construction.
    """
    nan = float('nan')
    if len(xy0) < max(min_inliers, 5):
        return Motion(0, nan, nan, nan, True, nan)
    # USAC with local optimisation: a few ms even when blur leaves half the tracks wrong,
    # where plain RANSAC runs to its iteration cap (tens of ms). Seeded: deterministic.
    E, mask = cv2.findEssentialMat(xy0, xy1, np.eye(3), cv2.USAC_FAST, 0.99, 2.0 * sigma_norm,
                                   200)
    if E is None or E.shape != (3, 3):
        return Motion(0, nan, nan, nan, True, nan)
    inl = mask.ravel().astype(bool)
    n_inl = int(np.count_nonzero(inl))
    if n_inl < max(min_inliers, min_inlier_ratio * len(xy0)):
        return Motion(n_inl, nan, nan, nan, True, nan)
    a, b = xy0[inl], xy1[inl]
    sigma_sq = sigma_norm * sigma_norm
    g_e = gric(sampson_sq(E, xy0, xy1), sigma_sq, 3, 5)
    if rot_sq is None:
        _, rot_sq = rotation_fit(xy0, xy1)
    g_rot = gric(rot_sq, sigma_sq, 2, 3)
    parallax = float(np.sqrt(np.median(rot_sq[inl])))
    if g_rot <= g_e or parallax < min_parallax:
        return Motion(n_inl, g_e, g_rot, parallax, True, nan)
    _, R, t, _ = cv2.recoverPose(E, a, b, np.eye(3))
    depths = np.full(len(xy0), nan)
    depths[inl] = unit_baseline_depths(R, t.ravel(), a, b)
    ratio = float(1.0 / np.nanmedian(depths)) if np.any(np.isfinite(depths)) else nan
    return Motion(n_inl, g_e, g_rot, parallax, not np.isfinite(ratio), ratio, depths, R,
                  t.ravel())


def sharpness(grey: npt.NDArray[np.uint8]) -> float:
    """Variance of the Laplacian of a grey image (higher is sharper)."""
    return float(cv2.Laplacian(grey, cv2.CV_32F).var())


def target_area_fraction(vertices_px: FloatArray, object_ids: npt.NDArray[np.int64],
                         width: int, height: int) -> float:
    """
    Largest detected target's area as a fraction of the image.

    :param vertices_px: (N, 2) image vertices (u, v), px; :param object_ids: (N,) their object.
    """
    best = 0.0
    for obj in np.unique(object_ids):
        pts = vertices_px[object_ids == obj].astype(np.float32)
        if len(pts) >= 3:
            best = max(best, float(cv2.contourArea(cv2.convexHull(pts))))
    return best / float(width * height)


def nominal_camera(width: int, height: int, hfov_deg: float = 65.0) -> CameraModel:
    """A distortion-free camera of typical field of view, for when no camera_info is known."""
    f_px = 0.5 * width / np.tan(np.deg2rad(0.5 * hfov_deg))
    K = np.array([[f_px, 0.0, 0.5 * (width - 1)], [0.0, f_px, 0.5 * (height - 1)],
                  [0.0, 0.0, 1.0]])
    return CameraModel(width, height, K)
