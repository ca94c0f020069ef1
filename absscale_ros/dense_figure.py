"""
A picture of a dense cloud: the points splatted into a virtual camera behind the scan (a
z-buffer in numpy; Open3D's offscreen renderer needs a display), coloured, and beside it the
same view shaded by the normals so surface noise shows.
"""
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


def viewpoint(xyz: FloatArray, cameras: list[FloatArray], back: float = 0.3,
              rise: float = 0.5) -> FloatArray:
    """T_world_cam of a virtual camera behind and above the mean keyframe, looking at the
    cloud's median point (``back`` and ``rise`` in units of that distance)."""
    centre = np.mean([T[:3, 3] for T in cameras], axis=0)
    target = np.median(xyz, axis=0)
    down = np.mean([T[:3, 1] for T in cameras], axis=0)
    down /= np.linalg.norm(down)
    z = target - centre
    eye = centre - back * z - rise * np.linalg.norm(z) * down
    z = target - eye
    z = z / np.linalg.norm(z)
    x = np.cross(down, z)
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    T[:3, 3] = eye
    return T


def splat(xyz: FloatArray, colours: npt.NDArray[np.uint8], T_world_cam: FloatArray,
          size: tuple[int, int] = (960, 540), radius: int = 1) -> npt.NDArray[np.uint8]:
    """RGB image of points as (2 radius + 1)^2 squares, nearest first (z-buffer); the focal
    length frames the central 96 % of the points."""
    w, h = size
    p = (xyz - T_world_cam[:3, 3]) @ T_world_cam[:3, :3]
    ok = p[:, 2] > 0.1
    p, col = p[ok], colours[ok]
    spread = np.percentile(np.abs(p[:, :2] / p[:, 2:]), 98, axis=0)
    f = 0.95 * min(w / 2 / spread[0], h / 2 / spread[1])
    u = np.round(f * p[:, 0] / p[:, 2] + w / 2).astype(int)
    v = np.round(f * p[:, 1] / p[:, 2] + h / 2).astype(int)
    order = np.argsort(-p[:, 2])  # far first: nearer points overwrite them
    image = np.full((h, w, 3), 255, np.uint8)
    for du in range(-radius, radius + 1):
        for dv in range(-radius, radius + 1):
            uu, vv = u[order] + du, v[order] + dv
            inside = (uu >= 0) & (uu < w) & (vv >= 0) & (vv < h)
            image[vv[inside], uu[inside]] = col[order][inside]
    return image


def draw(path: Path, xyz: FloatArray, rgb: npt.NDArray[np.uint8], normals: FloatArray,
         cameras: list[FloatArray], title: str) -> None:
    """Colour and normal-shaded views side by side, with a title, as a PNG."""
    T = viewpoint(xyz, cameras)
    light = T[:3, :3] @ np.array([-0.4, -0.6, -0.7])
    shade = np.clip(np.abs(normals @ light) / np.linalg.norm(light), 0, 1)
    grey = (40 + 200 * shade).astype(np.uint8)
    left = splat(xyz, rgb, T)
    right = splat(xyz, np.stack([grey] * 3, axis=1), T)
    image = np.concatenate([left, np.full((left.shape[0], 8, 3), 255, np.uint8), right], 1)
    band = np.full((40, image.shape[1], 3), 255, np.uint8)
    cv2.putText(band, title, (10, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (0, 0, 0), 2)
    cv2.imwrite(str(path), cv2.cvtColor(np.concatenate([band, image], 0), cv2.COLOR_RGB2BGR))
