"""The dense cloud message (x y z, packed rgb, normals) read back byte by byte and by module."""
import struct

from absscale_ros import conversions
import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import PointCloud2, PointField


def test_dense_cloud_layout_and_round_trip() -> None:
    rng = np.random.default_rng(3)
    xyz = rng.normal(size=(50, 3)) * 10
    rgb = rng.integers(0, 256, size=(50, 3), dtype=np.uint8)
    normals = rng.normal(size=(50, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    msg = conversions.dense_cloud_msg(xyz, rgb, normals, 123_000_000_456, 'map')
    msg = deserialize_message(serialize_message(msg), PointCloud2)  # as a subscriber gets it
    names = [f.name for f in msg.fields]
    assert names == ['x', 'y', 'z', 'rgb', 'normal_x', 'normal_y', 'normal_z']
    assert all(f.datatype == PointField.FLOAT32 and f.count == 1 for f in msg.fields)
    assert msg.header.frame_id == 'map' and msg.width == 50 and msg.height == 1
    assert conversions.stamp_to_ns(msg.header.stamp) == 123_000_000_456
    off = {f.name: f.offset for f in msg.fields}
    for i in (0, 17, 49):  # PCL's layout, decoded without the module
        base = i * msg.point_step
        x, y, z = struct.unpack_from('<3f', msg.data, base + off['x'])
        packed, = struct.unpack_from('<I', msg.data, base + off['rgb'])
        nx, = struct.unpack_from('<f', msg.data, base + off['normal_x'])
        assert np.allclose([x, y, z], xyz[i], atol=1e-5 * np.abs(xyz[i]).max())
        assert (packed >> 16 & 255, packed >> 8 & 255, packed & 255) == tuple(rgb[i])
        assert nx == pytest.approx(normals[i, 0], abs=1e-6)
    back_xyz, back_rgb, back_n = conversions.cloud_msg_to_xyz_rgb_normals(msg)
    assert np.allclose(back_xyz, xyz, atol=1e-4) and np.array_equal(back_rgb, rgb)
    assert np.allclose(back_n, normals, atol=1e-6)


def test_sparse_cloud_reads_without_normals_and_bad_normals_refused() -> None:
    msg = conversions.xyz_rgb_to_cloud_msg(np.ones((4, 3)), np.zeros((4, 3), np.uint8))
    xyz, rgb, normals = conversions.cloud_msg_to_xyz_rgb_normals(msg)
    assert xyz.shape == (4, 3) and rgb.shape == (4, 3) and normals is None
    with pytest.raises(ValueError):
        conversions.dense_cloud_msg(np.ones((4, 3)), np.zeros((4, 3), np.uint8), np.ones((3, 3)))
