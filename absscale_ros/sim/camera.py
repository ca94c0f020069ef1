"""
Simulated camera: intrinsics drawn per seed, plumb_bob projection and its exact inverse.

Pixel convention (ROS / OpenCV): the centre of pixel column ``i`` is at ``u = i``. Camera frame
is the ROS optical frame (x right, y down, z forward). The renderer casts one ray through each
*distorted* pixel position, so rendered images carry exactly the distortion the bag's
CameraInfo states, and ``project`` is the same model the ground-truth 2D vertices use.
"""
import numpy as np
import numpy.typing as npt

from absscale_ros.core.types import CameraModel

FloatArray = npt.NDArray[np.float64]


def make_camera(rng: np.random.Generator, width: int = 1280, height: int = 720) -> CameraModel:
    """
    Draw a handheld-camera model: 60-70 degrees horizontal field of view, mild radial distortion.

    :param rng: source of the per-seed variation.
    :param width: image width, px.
    :param height: image height, px.
    :returns: plumb_bob camera model (k1 k2 p1 p2 k3).
    """
    hfov_rad = np.deg2rad(rng.uniform(60.0, 70.0))
    fx = 0.5 * width / np.tan(0.5 * hfov_rad)
    fy = fx * rng.uniform(0.998, 1.002)  # square pixels up to calibration noise
    cx = 0.5 * (width - 1) + rng.uniform(-0.01, 0.01) * width
    cy = 0.5 * (height - 1) + rng.uniform(-0.01, 0.01) * height
    # Mild barrel distortion, as in phone / action cameras with a corrected lens.
    dist = np.array([rng.uniform(-0.12, -0.04), rng.uniform(0.0, 0.05),
                     rng.uniform(-5e-4, 5e-4), rng.uniform(-5e-4, 5e-4), 0.0])
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    return CameraModel(width, height, K, dist, 'plumb_bob')


def distort_normalized(xy: FloatArray, dist: FloatArray) -> FloatArray:
    """
    Apply plumb_bob distortion to normalised image coordinates.

    :param xy: (N, 2) undistorted normalised coordinates (x/z, y/z).
    :param dist: (5,) k1 k2 p1 p2 k3.
    :returns: (N, 2) distorted normalised coordinates.
    """
    k1, k2, p1, p2, k3 = (float(c) for c in np.resize(np.append(dist, np.zeros(5)), 5)[:5])
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([xd, yd], axis=1)


def project(camera: CameraModel, points_cam_m: FloatArray) -> FloatArray:
    """
    Project camera-frame points to distorted pixel positions.

    :param camera: plumb_bob or distortion-free model.
    :param points_cam_m: (N, 3) points in the camera optical frame, m.
    :returns: (N, 2) pixel positions (u, v), px; NaN for points with z <= 0.
    """
    pts = np.asarray(points_cam_m, dtype=np.float64).reshape(-1, 3)
    with np.errstate(divide='ignore', invalid='ignore'):
        xy = pts[:, :2] / pts[:, 2:3]
    if camera.has_distortion:
        xy = distort_normalized(xy, camera.dist)
    K = camera.K
    uv = np.stack([K[0, 0] * xy[:, 0] + K[0, 1] * xy[:, 1] + K[0, 2],
                   K[1, 1] * xy[:, 1] + K[1, 2]], axis=1)
    uv[pts[:, 2] <= 0.0] = np.nan
    return uv


def undistort_pixels(camera: CameraModel, pixels_px: FloatArray,
                     iterations: int = 30) -> FloatArray:
    """
    Invert ``project`` for pixel positions: Newton iterations on the distortion model.

    The fixed-point scheme of cv2.undistortPoints leaves ~0.01 px errors at the corners with
    barrel distortion; Newton with the analytic Jacobian converges to 1e-9 px.

    :param pixels_px: (N, 2) distorted pixel positions, px.
    :returns: (N, 2) undistorted normalised coordinates (x/z, y/z).
    """
    uv = np.asarray(pixels_px, dtype=np.float64).reshape(-1, 2)
    K = camera.K
    yd = (uv[:, 1] - K[1, 2]) / K[1, 1]
    xd = (uv[:, 0] - K[0, 2] - K[0, 1] * yd) / K[0, 0]
    target = np.stack([xd, yd], axis=1)
    if not camera.has_distortion:
        return target
    xy = target.copy()
    eps = 1e-7
    for _ in range(iterations):
        f0 = distort_normalized(xy, camera.dist) - target
        if np.max(np.abs(f0)) < 1e-13:
            break
        # Jacobian by central differences: the model is smooth and this stays readable.
        jx = (distort_normalized(xy + [eps, 0.0], camera.dist)
              - distort_normalized(xy - [eps, 0.0], camera.dist)) / (2 * eps)
        jy = (distort_normalized(xy + [0.0, eps], camera.dist)
              - distort_normalized(xy - [0.0, eps], camera.dist)) / (2 * eps)
        det = jx[:, 0] * jy[:, 1] - jy[:, 0] * jx[:, 1]
        dx = (jy[:, 1] * f0[:, 0] - jy[:, 0] * f0[:, 1]) / det
        dy = (-jx[:, 1] * f0[:, 0] + jx[:, 0] * f0[:, 1]) / det
        xy[:, 0] -= dx
        xy[:, 1] -= dy
    return xy


def ray_directions(camera: CameraModel, pixels_px: FloatArray) -> npt.NDArray[np.float32]:
    """
    Unit ray directions in the camera frame through distorted pixel positions.

    :param pixels_px: (N, 2) pixel positions, px.
    :returns: (N, 3) float32 unit vectors, camera optical frame.
    """
    xy = undistort_pixels(camera, pixels_px)
    dirs = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    return dirs.astype(np.float32)


def pixel_grid(width: int, height: int, step: int = 1,
               offset_px: tuple[float, float] = (0.0, 0.0)) -> FloatArray:
    """
    Pixel positions of a regular grid, row-major.

    :param step: grid spacing, px; with ``step > 1`` the grid also covers ``width`` and
        ``height`` so every pixel lies inside a grid cell.
    :param offset_px: (du, dv) added to every position (sub-pixel samples).
    :returns: (rows * cols, 2) positions (u, v), px.
    """
    us = np.arange(0, width + (step if step > 1 else 0), step, dtype=np.float64)
    vs = np.arange(0, height + (step if step > 1 else 0), step, dtype=np.float64)
    u, v = np.meshgrid(us + offset_px[0], vs + offset_px[1])
    return np.stack([u.ravel(), v.ravel()], axis=1)
