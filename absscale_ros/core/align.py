"""Similarity alignment of two point sets (Umeyama 1991), for evaluation against ground truth."""
import numpy as np
import numpy.typing as npt

from absscale_ros.core import errors

FloatArray = npt.NDArray[np.float64]


def umeyama(src: FloatArray, dst: FloatArray) -> tuple[float, FloatArray, FloatArray]:
    """
    Least-squares Sim(3) with ``dst ~ s * R @ src + t``.

    :param src: (N, 3) points, any unit (e.g. SfM units).
    :param dst: (N, 3) corresponding points (e.g. metres).
    :returns: scale s, (3, 3) rotation R, (3,) translation t.
    :raises errors.DegenerateGeometryError: for fewer than 3 points or collapsed ``src``.
    """
    src, dst = np.asarray(src, np.float64), np.asarray(dst, np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise ValueError(f'need two (N, 3) arrays, got {src.shape} and {dst.shape}')
    if len(src) < 3:
        raise errors.DegenerateGeometryError(f'{len(src)} points < 3 for a similarity')
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    var_s = float((xs**2).sum()) / len(src)
    if var_s < 1e-18:
        raise errors.DegenerateGeometryError('source points coincide')
    U, D, Vt = np.linalg.svd(xd.T @ xs / len(src))
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:  # reflection -> nearest rotation (eq. 39)
        S[2, 2] = -1.0
    R = U @ S @ Vt
    s = float(np.trace(np.diag(D) @ S)) / var_s  # eq. 42
    return s, R, mu_d - s * R @ mu_s


def pose_similarity(T_src: FloatArray, T_dst: FloatArray) -> tuple[float, FloatArray, FloatArray]:
    """
    Sim(3) with ``dst ~ s * R @ src + t`` from poses: R from their orientations, s and t from
    their centres given R (least squares).

    The centres of a nearly straight path fix the roll about it poorly: in simulator bags the
    centres-only rotation (``umeyama``) was 0.2-1.3 degrees off where the orientations agree to
    0.03-0.06, and swung target vertices 1-6 m from the path by 5-20 mm. R is the rotation
    nearest the sum of ``R_dst_i @ R_src_i^T`` (the chordal mean of the orientation offsets).

    :param T_src: (N, 4, 4) T_world_cam, any unit (e.g. SfM units).
    :param T_dst: (N, 4, 4) T_world_cam of the same cameras (e.g. metres).
    :returns: scale s, (3, 3) rotation R, (3,) translation t.
    :raises errors.DegenerateGeometryError: for fewer than 3 poses or coinciding centres.
    """
    T_src, T_dst = np.asarray(T_src, np.float64), np.asarray(T_dst, np.float64)
    if T_src.shape != T_dst.shape or T_src.ndim != 3 or T_src.shape[1:] != (4, 4):
        raise ValueError(f'need two (N, 4, 4) arrays, got {T_src.shape} and {T_dst.shape}')
    if len(T_src) < 3:
        raise errors.DegenerateGeometryError(f'{len(T_src)} poses < 3 for a similarity')
    U, _, Vt = np.linalg.svd(np.einsum('nij,nkj->ik', T_dst[:, :3, :3], T_src[:, :3, :3]))
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    src, dst = T_src[:, :3, 3], T_dst[:, :3, 3]
    xs, xd = src - src.mean(0), dst - dst.mean(0)
    var_s = float((xs**2).sum())
    if var_s < 1e-18 * len(src):
        raise errors.DegenerateGeometryError('source centres coincide')
    s = float(np.sum(xd * (xs @ R.T))) / var_s
    return s, R, dst.mean(0) - s * R @ src.mean(0)


def apply(s: float, R: FloatArray, t: FloatArray, points: FloatArray) -> FloatArray:
    """Return ``s * R @ p + t`` for each row of ``points`` (N, 3)."""
    return s * np.asarray(points) @ R.T + t


def rmse(a: FloatArray, b: FloatArray) -> float:
    """Root mean square Euclidean distance between rows of (N, 3) ``a`` and ``b``."""
    return float(np.sqrt(np.mean(np.sum((np.asarray(a) - np.asarray(b))**2, axis=1))))
