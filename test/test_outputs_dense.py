"""`absscale run` with the dense node on: dense_cloud.ply beside the sparse scaled cloud."""
from pathlib import Path

from absscale_ros import conversions, outputs
from absscale_ros.core import cloud
import numpy as np
from rclpy.serialization import serialize_message
from sensor_msgs.msg import PointCloud2


def test_dense_and_sparse_clouds_go_to_their_files(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    dense_xyz = rng.normal(size=(300, 3))
    normals = dense_xyz / np.linalg.norm(dense_xyz, axis=1, keepdims=True)
    rgb = rng.integers(0, 256, size=(300, 3), dtype=np.uint8)
    sparse_xyz = rng.normal(size=(12, 3))
    latest = {
        '/scaled_cloud': (PointCloud2, serialize_message(
            conversions.dense_cloud_msg(dense_xyz, rgb, normals, 5))),
        '/absscale/sparse_cloud_metric': (PointCloud2, serialize_message(
            conversions.xyz_rgb_to_cloud_msg(sparse_xyz, rgb[:12], 5))),
    }
    written = outputs.write_run_outputs(latest, tmp_path, {'bag': 'x.mcap', 'nodes': {}})
    assert written['dense_cloud.ply'] == {'points': 300}
    assert written['scaled_cloud.ply'] == {'points': 12}
    xyz, colours = cloud.read_ply(tmp_path / 'dense_cloud.ply')
    assert np.allclose(xyz, dense_xyz, atol=1e-5) and np.array_equal(colours, rgb)
    import open3d as o3d
    pc = o3d.io.read_point_cloud(str(tmp_path / 'dense_cloud.ply'))
    assert pc.has_normals() and np.allclose(np.asarray(pc.normals), normals, atol=1e-6)
    assert np.allclose(cloud.read_ply(tmp_path / 'scaled_cloud.ply')[0], sparse_xyz, atol=1e-5)
