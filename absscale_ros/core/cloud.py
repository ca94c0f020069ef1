"""
Point-cloud and trajectory files: PLY through Open3D, TUM text for trajectories.

Open3D stays inside this module (numpy in, numpy out), as the house style asks.
"""
from pathlib import Path

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


def write_ply(path: Path, points: FloatArray, colors: npt.NDArray[np.uint8] | None = None,
              normals: FloatArray | None = None) -> None:
    """
    Write a binary PLY readable by CloudCompare, MeshLab and Open3D: the bytes Open3D's own
    writer gives, without importing Open3D (2-5 s at the end of every run).

    :param points: (N, 3) positions (metres once scaled).
    :param colors: (N, 3) uint8 RGB, or None.
    :param normals: (N, 3) unit normals, or None.
    """
    # Open3D's property order: position, normal, colour.
    columns = [(('x', 'y', 'z'), '<f8', points)]
    if normals is not None and len(normals):
        columns.append((('nx', 'ny', 'nz'), '<f8', normals))
    if colors is not None and len(colors):
        columns.append((('red', 'green', 'blue'), 'u1', colors))
    fields = [(name, kind) for names, kind, _ in columns for name in names]
    rows = np.empty(len(points), np.dtype(fields))
    for names, kind, values in columns:
        values = np.asarray(values, kind)
        for i, name in enumerate(names):
            rows[name] = values[:, i]
    header = ['ply', 'format binary_little_endian 1.0', 'comment Created by Open3D',
              f'element vertex {len(rows)}']
    header += [f'property {"double" if t == "<f8" else "uchar"} {n}' for n, t in fields]
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with open(path, 'wb') as f:
        f.write(('\n'.join(header + ['end_header']) + '\n').encode())
        f.write(rows.tobytes())


def read_ply(path: Path) -> tuple[FloatArray, npt.NDArray[np.uint8] | None]:
    """(N, 3) points and (N, 3) uint8 colours (None when the file has none)."""
    import open3d as o3d
    cloud = o3d.io.read_point_cloud(str(path))
    colors = (np.asarray(cloud.colors) * 255.0).round().astype(np.uint8) \
        if cloud.has_colors() else None
    return np.asarray(cloud.points), colors


def write_tum(path: Path, stamps_ns: npt.NDArray[np.int64], poses: FloatArray) -> None:
    """
    Write poses in the TUM format ``t x y z qx qy qz qw`` (t in seconds), as evo reads it.

    :param poses: (N, 7) ``x y z qx qy qz qw``, world from camera.
    """
    rows = [f'{int(t) // 1_000_000_000}.{int(t) % 1_000_000_000:09d} '
            + ' '.join(f'{v:.9f}' for v in pose) for t, pose in zip(stamps_ns, poses)]
    Path(path).write_text('\n'.join(rows) + ('\n' if rows else ''))


def read_tum(path: Path) -> tuple[npt.NDArray[np.int64], FloatArray]:
    """Inverse of :func:`write_tum`: (N,) stamps in ns and (N, 7) poses."""
    stamps, poses = [], []
    for line in Path(path).read_text().splitlines():
        if not line.strip() or line.startswith('#'):
            continue
        fields = line.split()
        sec, _, frac = fields[0].partition('.')
        stamps.append(int(sec) * 1_000_000_000 + int((frac + '000000000')[:9]))
        poses.append([float(v) for v in fields[1:8]])
    return np.array(stamps, np.int64), np.array(poses, np.float64).reshape(-1, 7)
