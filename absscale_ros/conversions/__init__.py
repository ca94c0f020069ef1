"""
The only package that turns ROS messages into numpy arrays and back, one module per kind of
message; every public name is imported here, so callers write
``from absscale_ros.conversions import ...``.

Readers are duck-typed: they work on rclpy message instances (``data`` is an ``array.array``)
and on messages deserialized by rosbags (``data`` is a numpy array), since both expose the same
field names. Expected failures (malformed or unsupported messages) raise
:class:`absscale_ros.core.errors.MessageError` with the numbers involved.

Speed notes (1280x720 bgr8, see ``test/bench/bench_conversions.py``): readers wrap
``msg.data``'s buffer in a strided ``np.ndarray`` (no copy), so a returned array shares memory
with the message (and is read-only for rosbags messages). Writers fill ``data`` with an
``array.array('B')`` built by ``frombytes`` from the array's buffer: one copy (0.1 ms),
which the generated setter stores as is only in a message made with ``check_fields=True``
(else it copies it again: 0.25 instead of 0.11 ms a frame). Assigning ``array.tobytes()``
costs two copies (1.7 ms) and, with ``ROS_PYTHON_CHECK_FIELDS=1``, a per-byte check (270 ms);
a memoryview or an ndarray goes through ``array.array('B', iterable)`` (130 ms or more).
"""
from absscale_ros.conversions.stamps import (  # noqa: F401
    ns_to_stamp, stamp_to_ns)
from absscale_ros.conversions.images import (  # noqa: F401
    array_to_image_msg, IMAGE_ENCODINGS, image_msg_to_array, image_msg_to_bgr)
from absscale_ros.conversions.compressed import (  # noqa: F401
    bgr_to_compressed_msg, compressed_bytes, compressed_format, compressed_msg_to_array,
    compressed_msg_to_bgr, image_geometry)
from absscale_ros.conversions.camera_info import (  # noqa: F401
    camera_info_to_model, camera_model_to_info_msg)
from absscale_ros.conversions.clouds import (  # noqa: F401
    array_to_cloud_msg, cloud_msg_to_array, cloud_msg_to_xyz_rgb_normals, cloud_stamp_and_size,
    dense_cloud_msg, pack_rgb, scaled_cloud_msg, unpack_rgb, xyz_rgb_to_cloud_msg)
from absscale_ros.conversions.paths import (  # noqa: F401
    path_msg_to_poses, poses_to_path_msg, tracked_step_from_msg, tracked_step_to_msg)
from absscale_ros.conversions.diagnostics import (  # noqa: F401
    ack_from_msg, ack_to_msg, diagnostic_array, diagnostic_status, diagnostic_summary,
    diagnostic_values, end_of_bag_msg)
from absscale_ros.conversions.scale_msg import (  # noqa: F401
    scale_from_msg, SCALE_LAYOUT, scale_to_msg)
