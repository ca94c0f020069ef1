"""
The picture of a run, ``run.png``: what was detected, how the scale converged, and a top view
of the metric cloud with a one-metre grid, for people who would rather look than read.
"""
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt


def draw_run(path: Path, detections: list[tuple[int, int]], history: list[dict[str, float]],
             cloud_m: npt.NDArray[np.float64] | None, colors: npt.NDArray[np.uint8] | None,
             trajectory_m: npt.NDArray[np.float64] | None,
             up: npt.NDArray[np.float64] | None, title: str) -> None:
    """
    Write a three-panel PNG.

    :param detections: (stamp_ns, vertices found) per frame.
    :param history: scale estimates in order, dicts with stamp_ns, factor, sigma.
    :param cloud_m: (N, 3) metric cloud (None before a scale exists).
    :param trajectory_m: (K, 3) keyframe positions, metres.
    :param up: unit "up" vector in the cloud's frame (see :func:`up_from_cameras`); the top
        view looks down along it. None: look down the frame's z axis.
    """
    import matplotlib
    matplotlib.use('Agg')  # no display on a site laptop's CI or over ssh
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 3, figsize=(16, 5), constrained_layout=True)
    fig.suptitle(title)
    _detections(axes[0], detections)
    _convergence(axes[1], history)
    basis = _plane_basis(up)
    _top_view(axes[2], None if cloud_m is None else cloud_m @ basis.T, colors,
              None if trajectory_m is None else trajectory_m @ basis.T)
    fig.savefig(path, dpi=80)
    plt.close(fig)


def main() -> None:
    """Draw from ``draw_run``'s arguments pickled on stdin (``outputs`` runs this apart), the
    camera orientations (``quats``, xyzw) given instead of ``up``."""
    import pickle
    import sys
    # Loaded before the arguments come: the caller starts this process before its run.
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot  # noqa: F401
    from scipy.spatial.transform import Rotation  # noqa: F401 (up_from_cameras)
    args = pickle.loads(sys.stdin.buffer.read())
    quats = args.pop('quats')
    args['up'] = up_from_cameras(quats) if quats is not None and len(quats) else None
    draw_run(**args)


def up_from_cameras(quats_xyzw: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """
    The mean "up" of handheld cameras: minus their optical y axis (y points down in the image).

    People film roughly upright, so this is a fair gravity direction without an IMU.
    """
    from scipy.spatial.transform import Rotation
    down = Rotation.from_quat(quats_xyzw).as_matrix()[:, :, 1].mean(axis=0)
    norm = np.linalg.norm(down)
    return -down / norm if norm > 1e-9 else np.array([0.0, 0.0, 1.0])


def _plane_basis(up: npt.NDArray[np.float64] | None) -> npt.NDArray[np.float64]:
    """(3, 3) rows: two horizontal axes and up, right-handed."""
    z = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, float)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z])


def _seconds(stamps_ns: list[int], t0: int) -> npt.NDArray[np.float64]:
    return (np.asarray(stamps_ns, np.int64) - t0) / 1e9


def _detections(ax: Any, detections: list[tuple[int, int]]) -> None:
    ax.set_title('calibration-object vertices per frame')
    ax.set_xlabel('time in bag, s')
    if not detections:
        ax.text(0.5, 0.5, 'no detector output', ha='center', transform=ax.transAxes)
        return
    stamps, counts = zip(*detections)
    t = _seconds(list(stamps), min(stamps))
    ax.step(t, counts, where='post', color='tab:blue')
    found = 100.0 * np.mean(np.asarray(counts) > 0)
    ax.set_ylabel(f'vertices (target in {found:.0f}% of frames)')


def _convergence(ax: Any, history: list[dict[str, float]]) -> None:
    ax.set_title('metric scale (factor +/- 2 sigma)')
    if not history:
        ax.text(0.5, 0.5, 'no scale established', ha='center', transform=ax.transAxes)
        return
    t0 = int(history[0]['stamp_ns'])
    t = _seconds([int(h['stamp_ns']) for h in history], t0)
    f = np.array([h['factor'] for h in history])
    s = np.array([h['sigma'] for h in history])
    ax.plot(t, f, 'o-', color='tab:green')
    ax.fill_between(t, f - 2 * s, f + 2 * s, color='tab:green', alpha=0.2)
    ax.set_xlabel('time since first estimate, s')
    ax.set_ylabel('metres per SfM unit')


def _top_view(ax: Any, cloud_m: Any, colors: Any, trajectory_m: Any) -> None:
    ax.set_title('top view, 1 m grid')
    ax.set_aspect('equal')
    if cloud_m is None or not len(cloud_m):
        ax.text(0.5, 0.5, 'no metric cloud', ha='center', transform=ax.transAxes)
        return
    c = None if colors is None else np.asarray(colors) / 255.0
    ax.scatter(cloud_m[:, 0], cloud_m[:, 1], s=1, c=c)
    if trajectory_m is not None and len(trajectory_m):
        ax.plot(trajectory_m[:, 0], trajectory_m[:, 1], 'r.-', lw=1, label='keyframes')
        ax.legend(loc='upper right')
    lo, hi = np.percentile(cloud_m[:, :2], [1, 99], axis=0)
    if trajectory_m is not None and len(trajectory_m):  # the whole walk stays in view
        lo = np.minimum(lo, trajectory_m[:, :2].min(axis=0))
        hi = np.maximum(hi, trajectory_m[:, :2].max(axis=0))
    lo, hi = lo - 0.5, hi + 0.5
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    # Grid lines every metre; labels at a step that stays readable on a 40 m scene.
    label_step = max(1, int(np.ceil(max(hi - lo) / 10.0)))
    for axis, a, b in ((ax.xaxis, lo[0], hi[0]), (ax.yaxis, lo[1], hi[1])):
        axis.set_ticks(np.arange(np.floor(a), np.ceil(b) + 1), minor=True)
        first = label_step * np.floor(a / label_step)
        axis.set_ticks(np.arange(first, np.ceil(b) + label_step, label_step))
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.grid(True, which='both', lw=0.4)
    ax.set_xlabel('x, m')
    ax.set_ylabel('y, m')
