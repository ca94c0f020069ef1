"""Shared helpers for the conversions tests: the rosbags (CDR) path for any rclpy message."""
from typing import Any, Callable

from rclpy.serialization import serialize_message
from rosbags.typesys import get_typestore, Stores

_TYPESTORE = get_typestore(Stores.ROS2_JAZZY)


def via_cdr(msg: Any) -> Any:
    """Return ``msg`` serialized by rclpy and deserialized by rosbags (numpy ``data`` fields)."""
    module = type(msg).__module__.split('.')[0]
    type_name = f'{module}/msg/{type(msg).__name__}'
    return _TYPESTORE.deserialize_cdr(serialize_message(msg), type_name)


def same(msg: Any) -> Any:
    return msg


# Every reader test runs on the rclpy message itself and on its rosbags twin.
READERS: dict[str, Callable[[Any], Any]] = {'rclpy': same, 'rosbags': via_cdr}
