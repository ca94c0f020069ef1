"""nav_msgs/Path to keyframe poses and back; tracked keyframe steps as transforms."""
from typing import Any

from absscale_ros.conversions.stamps import set_header, stamp_to_ns
from absscale_ros.core import errors
from absscale_ros.core.keyframes import TrackedStep
from geometry_msgs.msg import PoseStamped, TransformStamped
from nav_msgs.msg import Path
import numpy as np
import numpy.typing as npt


_UNIT_QUAT_TOL = 1e-3  # float32 round trips and printed YAML stay well inside this


def path_msg_to_poses(msg: Any) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """
    Return a ``nav_msgs/Path`` as poses and stamps.

    :returns: poses (N, 7) float64 ``[x y z qx qy qz qw]`` (position in the path's frame, quat_xyzw
        renormalised to unit length) and stamps_ns (N,) int64, each pose's own header stamp.
    :raises errors.MessageError: if a quaternion is not unit length (within 1e-3) or a value is
        not finite.
    """
    count = len(msg.poses)
    poses = np.empty((count, 7), dtype=np.float64)
    stamps_ns = np.empty(count, dtype=np.int64)
    for i, stamped in enumerate(msg.poses):
        p, q = stamped.pose.position, stamped.pose.orientation
        poses[i] = (p.x, p.y, p.z, q.x, q.y, q.z, q.w)
        stamps_ns[i] = stamp_to_ns(stamped.header.stamp)
    if not np.all(np.isfinite(poses)):
        bad = int(np.flatnonzero(~np.isfinite(poses).all(axis=1))[0])
        raise errors.MessageError(f'Path pose {bad} has NaN or inf: {poses[bad].tolist()}')
    norms = np.linalg.norm(poses[:, 3:], axis=1)
    off = np.flatnonzero(np.abs(norms - 1.0) > _UNIT_QUAT_TOL)
    if off.size:
        raise errors.MessageError(f'Path pose {int(off[0])} quaternion has norm '
                                  f'{norms[off[0]]:.6g}, not 1 ({off.size} of {count} poses)')
    poses[:, 3:] /= norms[:, None]
    return poses, stamps_ns


def poses_to_path_msg(poses: npt.ArrayLike, stamps_ns: npt.ArrayLike, frame_id: str = 'map',
                      stamp_ns: int | None = None) -> Path:
    """
    Return poses as a ``nav_msgs/Path``.

    :param poses: (N, 7) ``[x y z qx qy qz qw]``, position in m, quat_xyzw unit length.
    :param stamps_ns: (N,) stamp of each pose, ns.
    :param stamp_ns: the path's header stamp; by default the last pose's stamp (0 if empty).
    :raises ValueError: on mismatched shapes, non-finite values or non-unit quaternions.
    """
    poses = np.asarray(poses, dtype=np.float64)
    stamps = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
    if poses.ndim != 2 or poses.shape[1] != 7 or poses.shape[0] != stamps.shape[0]:
        raise ValueError(f'need poses (N, 7) and stamps (N,), got {poses.shape} and '
                         f'{stamps.shape}')
    norms = np.linalg.norm(poses[:, 3:], axis=1)
    if not np.all(np.isfinite(poses)) or np.any(np.abs(norms - 1.0) > _UNIT_QUAT_TOL):
        raise ValueError('poses must be finite with unit quat_xyzw')
    msg = Path()
    if stamp_ns is None:
        stamp_ns = int(stamps[-1]) if stamps.size else 0
    set_header(msg, stamp_ns, frame_id)
    out = []
    for pose, pose_stamp_ns in zip(poses.tolist(), stamps.tolist()):
        stamped = PoseStamped()
        set_header(stamped, pose_stamp_ns, frame_id)
        position, orientation = stamped.pose.position, stamped.pose.orientation
        position.x, position.y, position.z = pose[:3]
        orientation.x, orientation.y, orientation.z, orientation.w = pose[3:]
        out.append(stamped)
    msg.poses = out
    return msg


def _keyframe_frame(stamp_ns: int) -> str:
    return f'keyframe_{stamp_ns}'


def tracked_step_to_msg(step: TrackedStep | None, stamp_ns: int) -> TransformStamped:
    """
    A keyframe's tracked motion as the pose of its camera (``child_frame_id``
    ``keyframe_<stamp_ns>``) in the previous keyframe's camera frame (``header.frame_id``
    ``keyframe_<ref_stamp_ns>``); translation in units of the previous keyframe's median scene
    depth (scale-free). An unknown step (first keyframe, after a tracking loss) has an empty
    ``header.frame_id``, so every keyframe still gets a message.
    """
    msg = TransformStamped()
    set_header(msg, stamp_ns, '' if step is None else _keyframe_frame(step.ref_stamp_ns))
    msg.child_frame_id = _keyframe_frame(stamp_ns)
    if step is None:
        msg.transform.rotation.w = 1.0
        return msg
    t, q = msg.transform.translation, msg.transform.rotation
    t.x, t.y, t.z = (float(v) for v in step.centre)
    from scipy.spatial.transform import Rotation  # here: 0.36 s to import, in two nodes only
    q.x, q.y, q.z, q.w = (float(v) for v in Rotation.from_matrix(step.rotation.T).as_quat())
    return msg


def tracked_step_from_msg(msg: Any) -> TrackedStep | None:
    """
    The ``TrackedStep`` of ``tracked_step_to_msg`` (None: unknown step).

    :raises errors.MessageError: on a frame name that is not ``keyframe_<ns>``, or a
        non-finite translation or rotation.
    """
    parent = msg.header.frame_id
    if not parent:
        return None
    prefix, _, ns = parent.rpartition('_')
    t, q = msg.transform.translation, msg.transform.rotation
    centre = np.array([t.x, t.y, t.z], float)
    quat = np.array([q.x, q.y, q.z, q.w], float)
    if prefix != 'keyframe' or not ns.isdigit() or not np.all(np.isfinite(centre)) \
            or not np.isfinite(quat).all() or not np.linalg.norm(quat) > 0.5:
        raise errors.MessageError(f'bad tracked step: frame {parent!r}, translation {centre}, '
                                  f'rotation {quat}')
    from scipy.spatial.transform import Rotation
    return TrackedStep(int(ns), Rotation.from_quat(quat).as_matrix().T, centre)
