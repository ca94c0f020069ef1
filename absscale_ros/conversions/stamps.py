"""Message stamps and the shared helpers of the conversions modules."""
import array
from typing import Any

from absscale_ros.core import errors
from builtin_interfaces.msg import Time
import numpy as np


NS_PER_S = 1_000_000_000
_INT32_MIN, _INT32_MAX = -(2 ** 31), 2 ** 31 - 1


def stamp_to_ns(stamp: Any) -> int:
    """
    Return a ``builtin_interfaces/Time`` as integer nanoseconds.

    :param stamp: any object with integer ``sec`` and ``nanosec`` fields.
    :raises errors.MessageError: if ``nanosec`` is outside [0, 1e9).
    """
    sec, nanosec = int(stamp.sec), int(stamp.nanosec)
    if not 0 <= nanosec < NS_PER_S:
        raise errors.MessageError(f'stamp nanosec {nanosec} outside [0, {NS_PER_S})')
    return sec * NS_PER_S + nanosec


def ns_to_stamp(ns: int) -> Time:
    """
    Return integer nanoseconds as a ``builtin_interfaces/Time``.

    Negative times keep ``nanosec`` in [0, 1e9) and put the sign in ``sec``, as rclpy does.

    :raises ValueError: if the time does not fit the message's int32 seconds.
    """
    sec, nanosec = divmod(int(ns), NS_PER_S)
    if not _INT32_MIN <= sec <= _INT32_MAX:
        raise ValueError(f'{ns} ns does not fit builtin_interfaces/Time (int32 seconds)')
    return Time(sec=sec, nanosec=nanosec)


def set_header(msg: Any, stamp_ns: int, frame_id: str) -> None:
    msg.header.stamp = ns_to_stamp(stamp_ns)
    msg.header.frame_id = frame_id


def bytes_array(array_: np.ndarray) -> array.array:
    """Return the array's bytes as ``array.array('B')`` with one copy (see __init__.py)."""
    flat = np.ascontiguousarray(array_).reshape(-1).view(np.uint8)
    out = array.array('B')
    out.frombytes(flat)
    return out
