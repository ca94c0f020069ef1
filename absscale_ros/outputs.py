"""
The files of an offline run, from the last messages the graph published (see DESIGN.md).

``scaled_cloud.ply`` (metres), ``dense_cloud.ply`` (metres, with normals; dense node on),
``sparse_cloud.ply`` (SfM units), ``trajectory.tum`` (metres when
a scale was established, else SfM units, as report.json says).
"""
import os
from pathlib import Path
import pickle
import subprocess
import sys
import tempfile
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
    picture = _picture(msgs, out, report)  # drawn by another process meanwhile
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
    _, err = picture.communicate()
    written['run.png'] = {} if picture.returncode == 0 else {
        'skipped': f'drawing failed: {err.decode(errors="replace").strip()[-300:]}'}
    return written


def _picture(msgs: dict[str, Any], out: Path, report: dict[str, Any]) -> subprocess.Popen:
    """
    Start drawing ``run.png`` in a process of its own (``run_figure.main``): importing
    matplotlib and drawing a long run's cloud took 4.6 s, now beside the PLY files.
    """
    xyz = rgb = traj = quats = None
    if '/scaled_cloud' in msgs:
        xyz, rgb = _cloud_arrays(msgs['/scaled_cloud'])
    if '/absscale/scaled_path' in msgs:
        poses, _ = conversions.path_msg_to_poses(msgs['/absscale/scaled_path'])
        traj, quats = poses[:, :3], poses[:, 3:]
    scale_report = report.get('nodes', {}).get('scale', {})
    args = {'path': out / 'run.png', 'detections': report.get('detections', []),
            'history': scale_report.get('history', []), 'cloud_m': xyz, 'colors': rgb,
            'trajectory_m': traj, 'quats': quats,
            'title': f'absscale run: {Path(report["bag"]).name}'}
    with tempfile.TemporaryFile() as f:  # the child reads it before it is closed here
        f.write(pickle.dumps(args))
        f.seek(0)
        return subprocess.Popen(
            [sys.executable, '-c', 'from absscale_ros import run_figure; run_figure.main()'],
            stdin=f, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
            env=dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path)))
