"""
The files of an offline run, from the last messages the graph published (see DESIGN.md).

``scaled_cloud.ply`` (metres), ``dense_cloud.ply`` (metres, with normals; dense node on),
``sparse_cloud.ply`` (SfM units), ``trajectory.tum`` (metres when
a scale was established, else SfM units, as report.json says).
"""
from pathlib import Path
from typing import Any

from absscale_ros import conversions
from absscale_ros.core import cloud
import numpy as np
from rclpy.serialization import deserialize_message

SPARSE_METRIC_TOPIC = '/absscale/sparse_cloud_metric'


def _cloud_arrays(msg: Any) -> tuple[np.ndarray, np.ndarray | None]:
    pts = conversions.cloud_msg_to_array(msg, skip_nans=True)
    xyz = np.stack([pts[a] for a in 'xyz'], axis=1).astype(np.float64)
    rgb = conversions.unpack_rgb(pts['rgb']) if 'rgb' in (pts.dtype.names or ()) else None
    return xyz, rgb


def write_run_outputs(latest: dict[str, tuple[Any, bytes]], out: Path,
                      report: dict[str, Any]) -> dict[str, Any]:
    """Write whichever output files the graph's last messages allow; return what was written."""
    msgs = {topic: deserialize_message(data, cls) for topic, (cls, data) in latest.items()}
    written: dict[str, Any] = {}
    _picture(msgs, out, report)
    written['run.png'] = {}
    # With the dense node on (issue 9) /scaled_cloud is the dense cloud and the sparse metric
    # cloud comes on its own topic.
    dense = SPARSE_METRIC_TOPIC in msgs
    for topic, name in ((SPARSE_METRIC_TOPIC, 'scaled_cloud.ply'),
                        ('/scaled_cloud', 'dense_cloud.ply' if dense else 'scaled_cloud.ply'),
                        ('/absscale/sparse_cloud', 'sparse_cloud.ply')):
        if topic in msgs:
            xyz, rgb, normals = conversions.cloud_msg_to_xyz_rgb_normals(msgs[topic])
            if not len(xyz):
                written[name] = {'points': 0, 'skipped': 'the cloud is empty'}
                continue
            cloud.write_ply(out / name, xyz, rgb, normals)
            written[name] = {'points': len(xyz)}
    for topic, units in (('/absscale/scaled_path', 'metres'),
                         ('/absscale/keyframe_path', 'sfm units')):
        if topic in msgs:
            poses, stamps = conversions.path_msg_to_poses(msgs[topic])
            cloud.write_tum(out / 'trajectory.tum', stamps, poses)
            written['trajectory.tum'] = {'poses': len(poses), 'units': units}
            break
    return written


def _picture(msgs: dict[str, Any], out: Path, report: dict[str, Any]) -> None:
    from absscale_ros import run_figure
    xyz = rgb = traj = quats = None
    if '/scaled_cloud' in msgs:
        xyz, rgb = _cloud_arrays(msgs['/scaled_cloud'])
    if '/absscale/scaled_path' in msgs:
        poses, _ = conversions.path_msg_to_poses(msgs['/absscale/scaled_path'])
        traj, quats = poses[:, :3], poses[:, 3:]
    up = run_figure.up_from_cameras(quats) if quats is not None and len(quats) else None
    scale_report = report.get('nodes', {}).get('scale', {})
    run_figure.draw_run(out / 'run.png', report.get('detections', []),
                        scale_report.get('history', []), xyz, rgb, traj, up,
                        f'absscale run: {Path(report["bag"]).name}')
