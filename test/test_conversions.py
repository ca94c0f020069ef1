"""Round trips between ROS messages and numpy (absscale_ros.conversions)."""
import numpy as np
import pytest

from absscale_ros import conversions
from absscale_ros.core import errors


def test_stamp_round_trip_keeps_nanoseconds_and_negative_times() -> None:
    for ns in (0, 1, 999_999_999, 1_700_000_000_123_456_789, -1, -1_000_000_001):
        stamp = conversions.ns_to_stamp(ns)
        assert 0 <= stamp.nanosec < 1_000_000_000
        assert conversions.stamp_to_ns(stamp) == ns


def test_stamp_with_nanosec_overflow_is_rejected() -> None:
    stamp = conversions.ns_to_stamp(0)
    stamp.nanosec = 1_000_000_000
    with pytest.raises(errors.MessageError, match='1000000000'):
        conversions.stamp_to_ns(stamp)


def test_bgr8_image_msg_has_unpadded_rows() -> None:
    image = np.arange(4 * 6 * 3, dtype=np.uint8).reshape(4, 6, 3)
    msg = conversions.array_to_image_msg(image, 'bgr8', stamp_ns=5, frame_id='cam')
    assert (msg.height, msg.width, msg.step, msg.encoding) == (4, 6, 18, 'bgr8')
    assert bytes(msg.data) == image.tobytes()
    assert msg.header.frame_id == 'cam' and msg.header.stamp.nanosec == 5
