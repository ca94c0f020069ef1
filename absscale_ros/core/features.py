"""Keypoints, descriptors and verified matches between two keyframes (OpenCV, no ROS)."""
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core.types import CameraModel

FloatArray = npt.NDArray[np.float64]
IndexArray = npt.NDArray[np.int64]
# SURF is patented and AKAZE left OpenCV's main modules in 5.0 (cv2.AKAZE_create is gone).
DETECTORS = ('sift', 'orb')


@dataclass(frozen=True)
class FeatureConfig:
    """Detection and matching settings."""

    detector: str = 'sift'
    max_features: int = 2000
    sift_contrast: float = 0.004  # SIFT contrast threshold; OpenCV's 0.04 starves smooth walls
    ratio: float = 0.8  # Lowe's ratio test on the two nearest descriptors
    ransac_px: float = 1.5  # epipolar distance threshold of the fundamental-matrix check
    min_inliers: int = 20  # fewer verified matches than this is no match at all
    max_width_px: int = 640  # detect on a copy downscaled to this width (0: full size)
    # OpenCV's SIFT doubles its input (not the precise upscale) and halves the keypoints, which
    # puts them 0.25 px of the detection image right of and below the feature (flip test: an
    # image against its mirror, 0.250 in x and y; blobs at known positions: +0.250 / +0.252).
    # Subtracted from SIFT keypoints when set. Off: with 0.25 the scale error moved by -0.7
    # mm/m on average over 13 bags and the indoor sample's vertex error rose to 0.105 % (its
    # seed 1-3 figures are 0.06-0.15 % either way; session 13).
    sift_offset_px: float = 0.0
    # > 0: approximate k-d tree matching, leaves checked; 0: brute force. 16 leaves of 2 trees:
    # half the CPU of 32 of 4 (~40 ms a keyframe), 2.5-6 % fewer verified matches than brute
    # force (32 of 4: 1-1.5 %), the SfM as accurate on the tuning bags.
    flann_checks: int = 16
    flann_trees: int = 2  # randomised k-d trees of that index

    def __post_init__(self) -> None:
        if self.detector not in DETECTORS:
            raise ValueError(f'detector must be one of {DETECTORS}, got {self.detector!r}')
        if self.max_features < 8 or not 0.0 < self.ratio < 1.0 or self.ransac_px <= 0.0 or \
                self.max_width_px < 0 or self.flann_checks < 0 or self.flann_trees < 1 or \
                not abs(self.sift_offset_px) < 1.0:
            raise ValueError(f'bad feature config {self}')
        if self.min_inliers < 8:
            raise ValueError('min_inliers must be >= 8 (eight-point fundamental matrix)')


@dataclass(frozen=True, eq=False)
class Features:
    """
    Keypoints of one keyframe.

    :param keypoints_px: (N, 2) float64 distorted pixel positions as detected.
    :param points_px: (N, 2) float64 undistorted positions, px of the pinhole ``K``.
    :param descriptors: (N, D) float32 (SIFT) or uint8 (ORB/AKAZE) descriptors.
    :param colours_rgb: (N, 3) uint8 image colour at each keypoint.
    """

    keypoints_px: FloatArray
    points_px: FloatArray
    descriptors: npt.NDArray[np.generic]
    colours_rgb: npt.NDArray[np.uint8]


def undistort_px(camera: CameraModel, pixels_px: FloatArray) -> FloatArray:
    """
    Map distorted pixels to the ideal pinhole image with the same ``K``.

    :param pixels_px: (N, 2) distorted positions, px.
    :returns: (N, 2) undistorted positions, px.
    """
    pts = np.asarray(pixels_px, np.float64).reshape(-1, 1, 2)
    if not camera.has_distortion or len(pts) == 0:
        return pts.reshape(-1, 2).copy()
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)
    out = cv2.undistortPoints(pts, camera.K, camera.dist, None, camera.K, criteria=crit)
    return np.asarray(out, np.float64).reshape(-1, 2)


def _detector(cfg: FeatureConfig) -> cv2.Feature2D:
    if cfg.detector == 'sift':
        return cv2.SIFT_create(nfeatures=cfg.max_features, contrastThreshold=cfg.sift_contrast)
    return cv2.ORB_create(nfeatures=cfg.max_features)


def detect(image_bgr: npt.NDArray[np.uint8], camera: CameraModel, cfg: FeatureConfig) -> Features:
    """
    Detect keypoints and descriptors in one BGR image.

    :param image_bgr: (H, W, 3) uint8 image.
    """
    gray = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2GRAY)
    f = cfg.max_width_px / gray.shape[1] if 0 < cfg.max_width_px < gray.shape[1] else 1.0
    # SIFT doubles its input first, so a 640 px copy still localises to about 1.5 full-size px.
    small = gray if f == 1.0 else cv2.resize(gray, None, fx=f, fy=f, interpolation=cv2.INTER_AREA)
    kps, desc = _detector(cfg).detectAndCompute(small, None)
    if desc is None or not kps:
        return Features(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 128), np.float32),
                        np.zeros((0, 3), np.uint8))
    order = np.argsort([-k.response for k in kps], kind='stable')[:cfg.max_features]
    xy = cv2.KeyPoint_convert(kps)[order].astype(np.float64)
    if cfg.detector == 'sift':
        xy -= cfg.sift_offset_px
    xy = (xy + 0.5) / f - 0.5  # pixel centres
    ij = np.clip(np.rint(xy).astype(int), 0, [gray.shape[1] - 1, gray.shape[0] - 1])
    colours = image_bgr[ij[:, 1], ij[:, 0], ::-1].copy()
    return Features(xy, undistort_px(camera, xy), desc[order], colours)


class Index:
    """
    Two nearest neighbours among one keyframe's descriptors, built once and queried by several
    keyframes: approximate k-d trees (``flann_checks`` > 0, SIFT) or brute force.
    """

    def __init__(self, descriptors: npt.NDArray[np.generic], cfg: FeatureConfig) -> None:
        self._n = len(descriptors)
        self._checks = cfg.flann_checks if descriptors.dtype == np.float32 else 0
        if self._checks and self._n >= 2:
            cv2.setRNGSeed(0)  # the k-d trees are randomised: the same input, the same trees
            self._flann = cv2.flann_Index(descriptors, {'algorithm': 1, 'trees': cfg.flann_trees})
        else:
            self._bf = cv2.BFMatcher(cv2.NORM_L2 if descriptors.dtype == np.float32
                                     else cv2.NORM_HAMMING)
            self._train = descriptors

    def knn2(self, query: npt.NDArray[np.generic]) -> tuple[IndexArray, FloatArray]:
        """(M, 2) indices and (M, 2) distances of each query's two nearest neighbours."""
        if self._n < 2 or len(query) == 0:
            return np.zeros((0, 2), np.int64), np.zeros((0, 2))
        if self._checks:
            idx, d2 = self._flann.knnSearch(query, 2, params={'checks': self._checks})
            return idx.astype(np.int64), np.sqrt(np.maximum(d2.astype(np.float64), 0.0))
        knn = self._bf.knnMatch(query, self._train, k=2)
        return (np.array([[p[0].trainIdx, p[1].trainIdx] for p in knn], np.int64).reshape(-1, 2),
                np.array([[p[0].distance, p[1].distance] for p in knn]).reshape(-1, 2))


def match(a: Features, b: Features, cfg: FeatureConfig,
          b_subset: IndexArray | None = None, b_index: Index | None = None) -> IndexArray:
    """
    Ratio-test, mutually consistent matches (no geometric check yet).

    :param b_subset: match only these keypoints of ``b`` (indices), or all when None.
    :param b_index: ``Index(b.descriptors, cfg)``, reused across calls (ignored with
        ``b_subset``).
    :returns: (M, 2) int64 index pairs into ``a`` and ``b``.
    """
    b_idx = np.arange(len(b.descriptors)) if b_subset is None else np.asarray(b_subset)
    if len(a.descriptors) < 2 or len(b_idx) < 2:
        return np.zeros((0, 2), np.int64)
    if b_subset is not None or b_index is None:
        b_index = Index(b.descriptors[b_idx], cfg)
    else:
        b_idx = np.arange(len(b.descriptors))
    nn, dist = b_index.knn2(a.descriptors)
    good = np.flatnonzero(dist[:, 0] < cfg.ratio * dist[:, 1])
    if not len(good):
        return np.zeros((0, 2), np.int64)
    out = np.stack([good, b_idx[nn[good, 0]]], axis=1).astype(np.int64)
    # One keypoint of b may not be claimed twice: keep the first (best-ranked a) claim.
    _, first = np.unique(out[:, 1], return_index=True)
    return out[np.sort(first)]


def verify(points_a_px: FloatArray, points_b_px: FloatArray, cfg: FeatureConfig,
           rng: np.random.Generator) -> npt.NDArray[np.bool_]:
    """
    Geometric verification of putative matches with a RANSAC fundamental matrix.

    :param points_a_px: (M, 2) undistorted px in keyframe a.
    :param points_b_px: (M, 2) undistorted px in keyframe b.
    :param rng: unused (USAC seeds its own generator); kept so callers need not change.
    :returns: (M,) inlier mask; all False when fewer than ``cfg.min_inliers`` survive.
    """
    mask = np.zeros(len(points_a_px), bool)
    if len(points_a_px) < cfg.min_inliers:
        return mask
    # USAC (PROSAC, local optimisation, SPRT): ~4x less CPU than FM_RANSAC and more inliers
    # found at the same threshold; it seeds its own RNG, so the result is repeatable.
    F, inl = cv2.findFundamentalMat(points_a_px, points_b_px, cv2.USAC_ACCURATE, cfg.ransac_px,
                                    0.999)
    if F is None or inl is None or int(inl.sum()) < cfg.min_inliers:
        return mask
    return inl.ravel().astype(bool)
