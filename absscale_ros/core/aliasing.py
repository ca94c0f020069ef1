"""
Registrations that a repeated texture fooled: tests on a keyframe's PnP pose.

Pavers, tiles and bricks repeat every few metres. Under fast, blurred motion few true matches
survive, and one texture matched a period off is a rigid, self-consistent wrong motion: PnP
finds it with hundreds of inliers, all on the textured plane. Two symptoms give it away: the
camera would have jumped (its velocity reversed in a fraction of a second), and the structure
off that plane (objects, facades, decals seen at an angle) does not agree with the pose,
and the step points elsewhere than the one the keyframe selector tracked frame to frame.
"""
import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


def velocity_change(centres: FloatArray, stamps_ns: npt.NDArray[np.int64]) -> float:
    """
    ``|v2 - v1| / max(|v1|, |v2|)`` of the two steps between three camera centres.

    Scale-free: 0 for constant velocity, 1.4 for a right-angle turn at constant speed, 2 for
    a reversal.

    :param centres: (3, 3) camera centres, oldest first, any unit.
    :param stamps_ns: (3,) their stamps, increasing.
    """
    # Differences in int64 first: float64 holds an epoch stamp in ns only to ~256 ns.
    dt = np.diff(np.asarray(stamps_ns, np.int64)).astype(np.float64) * 1e-9
    v = np.diff(np.asarray(centres, np.float64), axis=0) / dt[:, None]
    fastest = max(float(np.linalg.norm(v[0])), float(np.linalg.norm(v[1])), 1e-300)
    return float(np.linalg.norm(v[1] - v[0])) / fastest


def velocity_reason(centres: FloatArray, stamps_ns: npt.NDArray[np.int64], max_change: float,
                    max_span_s: float, min_step: float = 0.0) -> str | None:
    """
    Why the newest of three camera centres is implausible (None: it is not, or the three span
    more than ``max_span_s``, over which a camera may well turn back, or both steps are shorter
    than ``min_step``: a camera nearly still moves by pose noise, which reverses its velocity at
    random, while an aliased pose jumps a texture period).
    """
    steps = np.linalg.norm(np.diff(np.asarray(centres, np.float64), axis=0), axis=1)
    if float(steps.max()) < min_step:
        return None
    span = np.diff(np.asarray(stamps_ns, np.int64))
    if np.any(span <= 0) or 1e-9 * float(span.sum()) > max_span_s:
        return None
    change = velocity_change(centres, stamps_ns)
    if change <= max_change:
        return None
    return (f' (its pose changes the velocity by {change:.2f} times the speed in '
            f'{1e-9 * float(span.sum()):.2f} s: repeated texture matched one period off?)')


def step_angle_deg(T_world_ref: FloatArray, T_world_new: FloatArray,
                   tracked_centre: FloatArray) -> float:
    """
    Angle between the step from ``T_world_ref`` to ``T_world_new`` (camera poses) and the
    same step as tracked frame to frame (``tracked_centre``: the new camera's centre in the
    reference camera's frame, any unit); 0 when either step has no length.
    """
    step = T_world_ref[:3, :3].T @ (T_world_new[:3, 3] - T_world_ref[:3, 3])
    norms = float(np.linalg.norm(step)) * float(np.linalg.norm(tracked_centre))
    if not norms > 0.0:
        return 0.0
    return float(np.degrees(np.arccos(np.clip(step @ tracked_centre / norms, -1.0, 1.0))))


def dominant_plane(points: FloatArray, tol: float, rng: np.random.Generator,
                   iterations: int = 100) -> BoolArray:
    """
    (N,) mask of the points within ``tol`` of the plane that holds most of (N, 3) ``points``.
    """
    n = len(points)
    if n < 3:
        return np.ones(n, bool)
    tri = points[rng.integers(0, n, size=(iterations, 3))]  # (I, 3, 3)
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norms = np.linalg.norm(normals, axis=1)
    good = norms > 1e-12
    if not np.any(good):
        return np.ones(n, bool)
    normals, tri = normals[good] / norms[good, None], tri[good]
    dist = np.abs(np.einsum('ik,nk->in', normals, points) -
                  np.einsum('ik,ik->i', normals, tri[:, 0])[:, None])
    near = dist < tol
    return near[int(np.argmax(near.sum(axis=1)))]


def off_plane_support(points: FloatArray, inliers: BoolArray, tol: float,
                      rng: np.random.Generator) -> tuple[float, float, int]:
    """
    Inlier rates of a pose's correspondences on and off their dominant plane.

    :param points: (N, 3) landmarks of every 2D-3D correspondence PnP was given.
    :param inliers: (N,) which of them the pose explains.
    :param tol: plane thickness, in the landmarks' unit.
    :returns: inlier rate on the plane, inlier rate off it, number of points off it.
    """
    on = dominant_plane(points, tol, rng)
    off = int((~on).sum())
    rate_on = float(inliers[on].mean()) if on.any() else 0.0
    rate_off = float(inliers[~on].mean()) if off else 0.0
    return rate_on, rate_off, off


def off_plane_reason(points: FloatArray, inliers: npt.NDArray[np.int64], plane_tol: float,
                     min_off: int, min_support: float, rng: np.random.Generator) -> str | None:
    """
    Why the structure off the dominant plane disowns a PnP pose (None: it does not).

    :param points: (N, 3) landmarks of every correspondence PnP was given.
    :param inliers: indices of those the pose explains.
    :param plane_tol: plane thickness over the landmarks' median distance from their median.
    :param min_off: fewer points off the plane decide nothing.
    :param min_support: the off-plane inlier rate must reach this share of the on-plane one.
    """
    mask = np.zeros(len(points), bool)
    mask[inliers] = True
    spread = float(np.median(np.linalg.norm(points - np.median(points, axis=0), axis=1)))
    on, off, n_off = off_plane_support(points, mask, plane_tol * spread, rng)
    if n_off < min_off or off >= min_support * on:
        return None
    return (f' ({100 * on:.0f} % of the points on the dominant plane agree with its pose, '
            f'{100 * off:.0f} % of the {n_off} off it: repeated texture?)')
