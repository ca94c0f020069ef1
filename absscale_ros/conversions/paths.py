"""nav_msgs/Path to keyframe poses and back; tracked keyframe steps as transforms."""
import math
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
    q.x, q.y, q.z, q.w = rotation_to_quat_xyzw(step.rotation.T)
    return msg


def rotation_to_quat_xyzw(m: npt.ArrayLike) -> tuple[float, float, float, float]:
    """
    The unit quaternion (x, y, z, w) of a rotation matrix, the same to the bit as scipy's
    ``Rotation.from_matrix(m).as_quat()`` for a proper rotation (its branch on the largest of
    the diagonal and the trace, then one normalisation). The keyframe selector's process
    needs no other part of scipy, whose import cost it 0.34 s of CPU.
    """
    m = np.asarray(m, dtype=np.float64)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    choice = int(np.argmax((m[0, 0], m[1, 1], m[2, 2], trace)))
    q = [0.0, 0.0, 0.0, 0.0]
    if choice == 3:
        q = [m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1], 1.0 + trace]
    else:
        i = choice
        j, k = (i + 1) % 3, (i + 2) % 3
        q[i] = 1.0 - trace + 2.0 * m[i, i]
        q[j] = m[j, i] + m[i, j]
        q[k] = m[k, i] + m[i, k]
        q[3] = m[k, j] - m[j, k]
    norm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    x, y, z, w = (float(v) / norm for v in q)
    return x, y, z, w


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
