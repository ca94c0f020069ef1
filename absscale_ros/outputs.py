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
from typing import Any, Callable

from absscale_ros import conversions
from absscale_ros.core import cloud
import numpy as np
from rclpy.serialization import deserialize_message

SPARSE_METRIC_TOPIC = '/absscale/sparse_cloud_metric'
# Niceness added to the drawing process: its matplotlib import (~1.4 s of CPU) gives way to
# the node processes starting at the same time (the replay waits for them), and it runs when a
# core is free; it draws at the end, when nothing else is left on the cores.
PICTURE_NICE = 10


def _cloud_arrays(msg: Any) -> tuple[np.ndarray, np.ndarray | None]:
    pts = conversions.cloud_msg_to_array(msg, skip_nans=True)
    xyz = np.stack([pts[a] for a in 'xyz'], axis=1).astype(np.float64)
    rgb = conversions.unpack_rgb(pts['rgb']) if 'rgb' in (pts.dtype.names or ()) else None
    return xyz, rgb


def write_run_outputs(latest: dict[str, tuple[Any, bytes]], out: Path,
                      report: dict[str, Any], picture: 'Picture | None' = None,
                      meanwhile: Callable[[], None] | None = None) -> dict[str, Any]:
    """
    Write whichever output files the graph's last messages allow; return what was written.

    :param picture: the drawing process, started before the run (default: started now).
    :param meanwhile: more work for the caller while ``run.png`` is drawn.
    """
    msgs = {topic: deserialize_message(data, cls) for topic, (cls, data) in latest.items()}
    own = picture is None
    picture = picture or Picture()
    try:
        return _write(msgs, out, report, picture, meanwhile)
    finally:
        if own:
            picture.close()


def _write(msgs: dict[str, Any], out: Path, report: dict[str, Any], picture: 'Picture',
           meanwhile: Callable[[], None] | None) -> dict[str, Any]:
    written: dict[str, Any] = {}
    picture.draw(_picture_args(msgs, out, report))  # by its own process, meanwhile
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
    if meanwhile is not None:
        meanwhile()
    written['run.png'] = picture.wait()
    return written


def _picture_args(msgs: dict[str, Any], out: Path, report: dict[str, Any]) -> dict[str, Any]:
    """``run_figure.main``'s arguments from the run's last messages and its report."""
    xyz = rgb = traj = quats = None
    if '/scaled_cloud' in msgs:
        xyz, rgb = _cloud_arrays(msgs['/scaled_cloud'])
    if '/absscale/scaled_path' in msgs:
        poses, _ = conversions.path_msg_to_poses(msgs['/absscale/scaled_path'])
        traj, quats = poses[:, :3], poses[:, 3:]
    scale_report = report.get('nodes', {}).get('scale', {})
    return {'path': out / 'run.png', 'detections': report.get('detections', []),
            'history': scale_report.get('history', []), 'cloud_m': xyz, 'colors': rgb,
            'trajectory_m': traj, 'quats': quats,
            'title': f'absscale run: {Path(report["bag"]).name}'}


class Picture:
    """
    ``run.png`` drawn by a process of its own (``run_figure.main``) beside the PLY files and
    the caller's own work (``write_run_outputs``' ``meanwhile``): importing matplotlib and
    drawing a long run's cloud took 4.6 s in the runner. Started before the run, it loads
    Python and matplotlib while the graph starts, then waits for ``draw``: the end of a split
    run of the 60 s bag waited 2.4 s for its outputs, the drawing and then the comparison with
    the ground truth, one after the other. ``close`` ends it if it was never used.
    """

    def __init__(self) -> None:
        self._proc = subprocess.Popen(
            [sys.executable, '-c', 'from absscale_ros import run_figure; run_figure.main()'],
            stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
            env=dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path)),
            preexec_fn=lambda: os.nice(PICTURE_NICE))

    def draw(self, args: dict[str, Any]) -> None:
        """Hand it ``draw_run``'s arguments (``quats`` instead of ``up``, see ``main``)."""
        assert self._proc.stdin is not None
        try:
            self._proc.stdin.write(pickle.dumps(args))
            self._proc.stdin.close()
        except BrokenPipeError:
            pass  # it died loading: ``wait`` says why

    def wait(self, timeout_s: float = 120.0) -> dict[str, Any]:
        """
        The ``outputs`` entry of ``run.png``: {} once drawn, else why it was not. A drawing
        that hangs is killed after ``timeout_s`` (the run's other outputs are written by then).
        """
        assert self._proc.stderr is not None
        try:  # stderr is only a traceback, well inside a pipe's buffer
            self._proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
            return {'skipped': f'drawing took longer than {timeout_s:g} s'}
        err = self._proc.stderr.read()
        return {} if self._proc.returncode == 0 else {
            'skipped': f'drawing failed: {err.decode(errors="replace").strip()[-300:]}'}

    def close(self) -> None:
        """End the process if it still waits (the run failed before drawing)."""
        if self._proc.poll() is None:
            self._proc.kill()
            self._proc.wait()
        for f in (self._proc.stdin, self._proc.stderr):
            if f is not None:
                f.close()
