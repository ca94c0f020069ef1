"""nav_msgs/Path <-> poses and diagnostic_msgs helpers (conversions)."""
from absscale_ros import conversions
from absscale_ros.core import errors
from conversions_helpers import READERS, via_cdr
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
import numpy as np
import pytest


def random_poses(count: int, seed: int = 5) -> np.ndarray:
    rng = np.random.default_rng(seed)
    quat_xyzw = rng.normal(size=(count, 4))
    quat_xyzw /= np.linalg.norm(quat_xyzw, axis=1, keepdims=True)
    return np.hstack([rng.normal(scale=3.0, size=(count, 3)), quat_xyzw])


@pytest.mark.parametrize('reader', READERS)
def test_path_round_trips_poses_and_per_pose_stamps(reader: str) -> None:
    poses = random_poses(6)
    stamps_ns = np.array([0, 10, 1_000_000_000, 1_500_000_001, 2_000_000_000, 3_999_999_999])
    msg = conversions.poses_to_path_msg(poses, stamps_ns, frame_id='odom')
    assert msg.header.frame_id == 'odom'
    assert conversions.stamp_to_ns(msg.header.stamp) == stamps_ns[-1]
    assert all(p.header.frame_id == 'odom' for p in msg.poses)
    # Order in the message: position x y z, then orientation x y z w.
    assert msg.poses[2].pose.orientation.w == poses[2, 6]
    assert msg.poses[2].pose.position.z == poses[2, 2]
    back_poses, back_stamps_ns = conversions.path_msg_to_poses(READERS[reader](msg))
    assert back_poses.dtype == np.float64 and back_stamps_ns.dtype == np.int64
    np.testing.assert_allclose(back_poses, poses, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(back_stamps_ns, stamps_ns)


def test_path_header_stamp_can_be_given_and_empty_paths_work() -> None:
    msg = conversions.poses_to_path_msg(random_poses(2), [5, 6], stamp_ns=99)
    assert conversions.stamp_to_ns(msg.header.stamp) == 99
    empty = conversions.poses_to_path_msg(np.zeros((0, 7)), [])
    assert conversions.stamp_to_ns(empty.header.stamp) == 0 and empty.header.frame_id == 'map'
    poses, stamps_ns = conversions.path_msg_to_poses(via_cdr(empty))
    assert poses.shape == (0, 7) and stamps_ns.shape == (0,)


@pytest.mark.parametrize('reader', READERS)
def test_non_unit_quaternion_in_a_path_is_rejected(reader: str) -> None:
    msg = conversions.poses_to_path_msg(random_poses(3), [1, 2, 3])
    msg.poses[1].pose.orientation.w *= 2.0
    with pytest.raises(errors.MessageError, match='pose 1 quaternion has norm'):
        conversions.path_msg_to_poses(READERS[reader](msg))
    msg.poses[1] = PoseStamped()
    msg.poses[1].pose.orientation.w = 0.0  # all-zero quaternion, as a careless publisher sends
    with pytest.raises(errors.MessageError, match='norm 0'):
        conversions.path_msg_to_poses(READERS[reader](msg))


def test_nan_in_a_path_is_rejected() -> None:
    msg = conversions.poses_to_path_msg(random_poses(2), [1, 2])
    msg.poses[0].pose.position.y = float('nan')
    with pytest.raises(errors.MessageError, match='pose 0 has NaN'):
        conversions.path_msg_to_poses(msg)


def test_poses_to_path_rejects_bad_input() -> None:
    with pytest.raises(ValueError, match=r'\(3, 7\) and \(2,\)'):
        conversions.poses_to_path_msg(random_poses(3), [1, 2])
    with pytest.raises(ValueError, match='unit'):
        conversions.poses_to_path_msg(np.zeros((1, 7)), [1])


# ------------------------------------------------------------------------------------------
# Diagnostics
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize('level,expected', [
    ('ok', DiagnosticStatus.OK), ('warn', DiagnosticStatus.WARN),
    ('ERROR', DiagnosticStatus.ERROR), ('stale', DiagnosticStatus.STALE),
    (DiagnosticStatus.WARN, DiagnosticStatus.WARN), (2, DiagnosticStatus.ERROR)])
def test_diagnostic_levels(level: object, expected: bytes) -> None:
    assert conversions.diagnostic_status('n', level, 'm').level == expected


@pytest.mark.parametrize('level', ['fine', 4, b'\x07', -1])
def test_unknown_diagnostic_level_is_rejected(level: object) -> None:
    with pytest.raises(ValueError, match='level'):
        conversions.diagnostic_status('n', level, 'm')


def test_diagnostic_values_are_compact_strings_and_survive_cdr() -> None:
    values = {'scale_m_per_unit': 0.1, 'frames_dropped': np.int64(3), 'stage_time_s': 1 / 3,
              'observable': False, 'big': 12345678.9, 'target': 'cube', 'nan': float('nan')}
    status = conversions.diagnostic_status('absscale/scale', 'warn', 'not yet observable', values,
                                           hardware_id='camera0')
    assert (status.name, status.message, status.hardware_id) == (
        'absscale/scale', 'not yet observable', 'camera0')
    array = conversions.diagnostic_array([status], stamp_ns=3_000_000_001)
    assert conversions.stamp_to_ns(array.header.stamp) == 3_000_000_001
    expected = {'scale_m_per_unit': '0.1', 'frames_dropped': '3', 'stage_time_s': '0.333333',
                'observable': 'False', 'big': '1.23457e+07', 'target': 'cube', 'nan': 'nan'}
    for read in READERS.values():
        msg = read(array)
        assert conversions.diagnostic_values(msg.status[0]) == expected
    assert conversions.diagnostic_values(conversions.diagnostic_status('n', 'ok', '')) == {}


def test_ack_and_diagnostic_summary_round_trip() -> None:
    stamp = conversions.ns_to_stamp(1_700_000_000_000_000_007)
    text, stamp_ns = conversions.ack_from_msg(conversions.ack_to_msg('sfm|/a|/b,/c', stamp))
    assert (text, stamp_ns) == ('sfm|/a|/b,/c', 1_700_000_000_000_000_007)
    arr = conversions.diagnostic_array(
        [conversions.diagnostic_status('scale: metric scale', 'warn', 'why', {'edges': 6})], 5)
    assert conversions.diagnostic_summary(arr) == {
        'scale: metric scale': {'level': 1, 'message': 'why', 'values': {'edges': '6'}}}


def test_tracked_step_quaternion_is_scipys_to_the_bit() -> None:
    # tracked_step_to_msg computes the quaternion itself (no scipy import in the frame nodes'
    # process); the sfm's results depend on its bits, so every branch must match scipy's.
    from absscale_ros.conversions.paths import rotation_to_quat_xyzw
    from scipy.spatial.transform import Rotation
    rng = np.random.default_rng(7)
    small = Rotation.from_rotvec(rng.normal(0.0, 0.05, (2000, 3))).as_matrix()
    half_turns = Rotation.from_rotvec(np.pi * np.eye(3) * 0.999).as_matrix()
    matrices = np.concatenate([Rotation.random(3000, random_state=8).as_matrix(), small,
                               half_turns])
    branches = set()
    for m in matrices:
        ours = rotation_to_quat_xyzw(m)
        assert ours == tuple(float(v) for v in Rotation.from_matrix(m).as_quat())
        branches.add(int(np.argmax((m[0, 0], m[1, 1], m[2, 2], np.trace(m)))))
    assert branches == {0, 1, 2, 3}
