"""Two-view geometry: relative pose initialisation, triangulation with angle/cheirality checks."""
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core import errors

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class TwoViewConfig:
    """Thresholds of initialisation and triangulation."""

    ransac_px: float = 1.0  # essential-matrix RANSAC threshold, px
    init_min_angle_deg: float = 2.0  # median triangulation angle of a usable initial pair
    init_min_points: int = 50  # triangulated points an initial pair must give
    max_h_ratio: float = 0.9  # share of matches a rotation homography explains: rotation
    max_h_deviation: float = 0.02  # |M M^T - I| of M = K^-1 H K (det 1) below this: rotation
    min_angle_deg: float = 1.0  # least ray angle of a new landmark
    max_reproj_px: float = 3.0  # largest reprojection error of a new landmark
    # A second motion (the first's outliers, translation this far off) explaining this share
    # of the first's points makes the pair ambiguous: repeated texture (pavers, tiles) matched
    # one period off fits a rigid wrong motion as well as the true one fits (1: off).
    max_second_motion: float = 0.25
    second_motion_deg: float = 15.0

    def __post_init__(self) -> None:
        if min(self.ransac_px, self.init_min_angle_deg, self.min_angle_deg,
               self.max_reproj_px, self.max_second_motion) <= 0.0 or \
                self.init_min_points < 8 or self.second_motion_deg < 0.0:
            raise ValueError(f'bad two-view config {self}')


def projection(K: FloatArray, T_world_cam: FloatArray) -> FloatArray:
    """(3, 4) projection matrix ``K [R^T | -R^T t]`` of a camera at ``T_world_cam`` (4, 4)."""
    R, t = T_world_cam[:3, :3], T_world_cam[:3, 3]
    return K @ np.hstack([R.T, (-R.T @ t)[:, None]])


def project(K: FloatArray, T_world_cam: FloatArray, points_world: FloatArray) -> FloatArray:
    """Pinhole projection of (N, 3) world points; returns (N, 2) px (inf behind the camera)."""
    p = (points_world - T_world_cam[:3, 3]) @ T_world_cam[:3, :3]
    z = np.where(p[:, 2] > 1e-12, p[:, 2], np.nan)
    uv = (p[:, :2] / z[:, None]) @ K[:2, :2].T + K[:2, 2]
    return np.where(np.isfinite(uv), uv, np.inf)


def triangulate(K: FloatArray, T_a: FloatArray, T_b: FloatArray, pts_a_px: FloatArray,
                pts_b_px: FloatArray, cfg: TwoViewConfig) -> tuple[FloatArray, BoolArray]:
    """
    Linear triangulation of matched undistorted pixels, then angle, cheirality, error checks.

    :param T_a: (4, 4) T_world_cam of view a; ``T_b`` likewise.
    :param pts_a_px: (N, 2) undistorted px in a; ``pts_b_px`` (N, 2) in b.
    :returns: (N, 3) world points and the (N,) mask of points passing every check.
    """
    if len(pts_a_px) == 0:
        return np.zeros((0, 3)), np.zeros(0, bool)
    X = cv2.triangulatePoints(projection(K, T_a), projection(K, T_b),
                              pts_a_px.T.astype(np.float64), pts_b_px.T.astype(np.float64))
    with np.errstate(divide='ignore', invalid='ignore'):
        pts = (X[:3] / X[3]).T
    ok = np.all(np.isfinite(pts), axis=1)
    ray_a, ray_b = pts - T_a[:3, 3], pts - T_b[:3, 3]
    cos = np.sum(ray_a * ray_b, 1) / (np.linalg.norm(ray_a, axis=1) *
                                      np.linalg.norm(ray_b, axis=1) + 1e-300)
    ok &= cos < np.cos(np.deg2rad(cfg.min_angle_deg))
    for T, uv in ((T_a, pts_a_px), (T_b, pts_b_px)):
        depth = (pts - T[:3, 3]) @ T[:3, 2]
        ok &= depth > 0.0
        err = np.linalg.norm(project(K, T, pts) - uv, axis=1)
        ok &= err < cfg.max_reproj_px
    return pts, ok


def median_angle_deg(T_a: FloatArray, T_b: FloatArray, points_world: FloatArray) -> float:
    """Median angle between the two rays to each of (N, 3) points, degrees."""
    ra, rb = points_world - T_a[:3, 3], points_world - T_b[:3, 3]
    cos = np.sum(ra * rb, 1) / (np.linalg.norm(ra, axis=1) * np.linalg.norm(rb, axis=1))
    return float(np.degrees(np.median(np.arccos(np.clip(cos, -1.0, 1.0)))))


def initialise(K: FloatArray, pts_a_px: FloatArray, pts_b_px: FloatArray, cfg: TwoViewConfig,
               rng: np.random.Generator) -> tuple[FloatArray, FloatArray, BoolArray]:
    """
    Relative pose of view b from view a, with the baseline scaled to 1 (SfM units).

    :param pts_a_px: (N, 2) undistorted px in a; ``pts_b_px`` (N, 2) in b (verified matches).
    :returns: T_world_cam of b with a at the origin (4, 4), (N, 3) points, (N,) good-point mask.
    :raises errors.DegenerateGeometryError: pure rotation, too little parallax or too few points.
    """
    if len(pts_a_px) < cfg.init_min_points:
        raise errors.DegenerateGeometryError(f'{len(pts_a_px)} matches < {cfg.init_min_points}')
    cv2.setRNGSeed(int(rng.integers(2**31 - 1)))
    motion = _essential_motion(K, pts_a_px, pts_b_px, cfg)
    if motion is None:
        raise errors.DegenerateGeometryError('no essential matrix')
    if _is_rotation(K, pts_a_px, pts_b_px, cfg):
        raise errors.DegenerateGeometryError('pure rotation: a rotation homography explains '
                                             'the matches')
    T_b, inl, _ = motion
    pts, ok = triangulate(K, np.eye(4), T_b, pts_a_px, pts_b_px, cfg)
    ok &= inl.ravel().astype(bool)
    if ok.sum() < cfg.init_min_points:
        raise errors.DegenerateGeometryError(f'{int(ok.sum())} points triangulated')
    angle = median_angle_deg(np.eye(4), T_b, pts[ok])
    if angle < cfg.init_min_angle_deg:
        raise errors.DegenerateGeometryError(f'too little parallax: median angle {angle:.2f} deg')
    rival = _second_motion(K, pts_a_px[~ok], pts_b_px[~ok], T_b[:3, 3], cfg)
    if rival >= cfg.max_second_motion * ok.sum():
        raise errors.DegenerateGeometryError(
            f'ambiguous pair: a second motion explains {rival} matches against {int(ok.sum())} '
            f'(repeated texture?)')
    return T_b, pts, ok


def _second_motion(K: FloatArray, pts_a_px: FloatArray, pts_b_px: FloatArray,
                   centre_b: FloatArray, cfg: TwoViewConfig) -> int:
    """
    Points in front of both cameras under the best motion of the matches the first motion left
    out, if its baseline points more than ``second_motion_deg`` away from ``centre_b`` (else 0).
    """
    motion = _essential_motion(K, pts_a_px, pts_b_px, cfg) if len(pts_a_px) >= 6 else None
    if motion is None:
        return 0
    T_b, _, n = motion
    c = T_b[:3, 3]
    cos = float(c @ centre_b) / (np.linalg.norm(c) * np.linalg.norm(centre_b) + 1e-300)
    return n if cos < np.cos(np.deg2rad(cfg.second_motion_deg)) else 0


def _essential_motion(K: FloatArray, pts_a_px: FloatArray, pts_b_px: FloatArray,
                      cfg: TwoViewConfig) -> tuple[FloatArray, npt.NDArray[np.uint8], int] | None:
    """
    RANSAC essential matrix and its pose: T_world_cam of b with a at the origin (4, 4), the
    RANSAC inlier mask (N, 1) and the number of points in front of both; None without an E.
    """
    E, inl = cv2.findEssentialMat(pts_a_px, pts_b_px, K, cv2.RANSAC, 0.999, cfg.ransac_px)
    if E is None or E.shape != (3, 3):
        return None
    n, R, t, _ = cv2.recoverPose(E, pts_a_px, pts_b_px, K, mask=inl.copy())
    T_b = np.eye(4)  # recoverPose gives b-from-a: x_b = R x_a + t
    T_b[:3, :3], T_b[:3, 3] = R.T, (-R.T @ t).ravel()
    return T_b, inl, int(n)


def _is_rotation(K: FloatArray, pts_a_px: FloatArray, pts_b_px: FloatArray,
                 cfg: TwoViewConfig) -> bool:
    """
    Pure rotation test: a homography explains nearly all matches and ``K^-1 H K`` is a rotation.

    (A plane seen with a real baseline also fits a homography, but not an orthogonal one.)
    """
    H, hin = cv2.findHomography(pts_a_px, pts_b_px, cv2.RANSAC, cfg.ransac_px)
    if H is None or hin is None or float(hin.mean()) < cfg.max_h_ratio:
        return False
    M = np.linalg.inv(K) @ H @ K
    M /= np.cbrt(np.linalg.det(M))
    return float(np.abs(M @ M.T - np.eye(3)).max()) < cfg.max_h_deviation
