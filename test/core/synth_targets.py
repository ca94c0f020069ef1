"""
Small synthetic target images for the detector tests (no simulator needed).

A cube or a sheet is projected with a pinhole camera, its faces filled with flat shading at
3x supersampling (so outlines are anti-aliased like a real image), then noise, optional
motion blur and JPEG compression are applied. The true 2D vertices come back with the image.
"""
import cv2
import numpy as np

from absscale_ros.core import targets

SS = 3  # supersampling factor
W, H = 1280, 720
K = np.array([[900.0, 0.0, (W - 1) / 2.0], [0.0, 900.0, (H - 1) / 2.0], [0.0, 0.0, 1.0]])
# BGR face colours: red H~0, yellow H~55, purple H~290 (DESIGN.md defaults).
FACE_BGR = {'red': (40, 35, 210), 'yellow': (40, 205, 225), 'purple': (170, 50, 140)}


def _background(rng, base_bgr=(90, 100, 110)):
    img = np.empty((H * SS, W * SS, 3), np.float32)
    img[:] = base_bgr
    return img


def _finish(img, rng, blur_px=0, noise=3.0, jpeg=90):
    img = cv2.resize(img, (W, H), interpolation=cv2.INTER_AREA)
    if blur_px > 1:
        k = np.zeros((blur_px, blur_px), np.float32)
        k[blur_px // 2, :] = 1.0 / blur_px
        img = cv2.filter2D(img, -1, k)
    img = img + rng.normal(0.0, noise, img.shape).astype(np.float32)
    img = np.clip(img, 0, 255).astype(np.uint8)
    ok, buf = cv2.imencode('.jpg', img, [cv2.IMWRITE_JPEG_QUALITY, jpeg])
    return cv2.imdecode(buf, cv2.IMREAD_COLOR)


def _project(points_cam):
    p = (K @ points_cam.T).T
    return p[:, :2] / p[:, 2:3]


def _fill(img, poly_px, bgr):
    pts = np.round((poly_px + 0.5) * SS * 16 - 0.5 * 16).astype(np.int32)  # 4 fractional bits
    cv2.fillConvexPoly(img, pts, bgr, lineType=cv2.LINE_8, shift=4)


def cube_pose(yaw_deg=35.0, pitch_deg=25.0, distance_m=5.0, offset_px=(0.0, 0.0)):
    """Return (R, t) of a cube 0.8 m seen obliquely (three faces)."""
    ry, rp = np.deg2rad(yaw_deg), np.deg2rad(pitch_deg)
    Rz = np.array([[np.cos(ry), -np.sin(ry), 0], [np.sin(ry), np.cos(ry), 0], [0, 0, 1]])
    Rx = np.array([[1, 0, 0], [0, np.cos(rp), -np.sin(rp)], [0, np.sin(rp), np.cos(rp)]])
    R = Rx @ np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]]) @ Rz  # world z up -> camera y down
    centre = np.array([offset_px[0] / 900.0 * distance_m, offset_px[1] / 900.0 * distance_m,
                       distance_m])
    return R, centre - R @ np.full(3, 0.4)


def render_cube(rng, R, t, blur_px=0, occluder=None, edge_m=0.8, background=None,
                extra=None):
    """
    Return (image, faces) with faces a list of (colour, (4, 2) corners px, vertex model ids).
    """
    model = targets.CubeModel(edge_m)
    v_cam = model.vertices_m() @ R.T + t
    v_px = _project(v_cam)
    img = _background(rng) if background is None else background
    faces = []
    light = np.array([0.3, -0.8, -0.5]) / np.linalg.norm([0.3, -0.8, -0.5])
    for axis, colour in enumerate(targets.CUBE_COLOURS):
        for side in (0, 1):
            ids = [i for i in range(8) if (i >> axis) & 1 == side]
            # order the 4 vertices around the face
            a, b = [(axis + 1) % 3, (axis + 2) % 3]
            order = sorted(ids, key=lambda i: {(0, 0): 0, (1, 0): 1, (1, 1): 2, (0, 1): 3}[
                ((i >> a) & 1, (i >> b) & 1)])
            normal_m = np.zeros(3)
            normal_m[axis] = 1.0 if side else -1.0
            n_cam = R @ normal_m
            centre_cam = v_cam[order].mean(0)
            if n_cam @ centre_cam >= 0.0:
                continue  # back face
            shade = 0.55 + 0.45 * max(0.0, float(-n_cam @ light))
            bgr = tuple(float(c) * shade for c in FACE_BGR[colour])
            _fill(img, v_px[order], bgr)
            faces.append((colour, v_px[order], order))
    if extra is not None:
        extra(img)
    if occluder is not None:
        _fill(img, np.asarray(occluder, float), (60, 60, 60))
    return _finish(img, rng, blur_px), faces, v_px


def render_sheet(rng, corners_px, paper_bgr=(235, 238, 240), desk_bgr=(70, 90, 120),
                 blur_px=0, extra=None):
    """Return an image of a sheet with the given (4, 2) corners on a darker desk."""
    img = _background(rng, desk_bgr)
    _fill(img, np.asarray(corners_px, float), paper_bgr)
    if extra is not None:
        extra(img)
    return _finish(img, rng, blur_px)


def fill(img, poly_px, bgr):
    """Fill a polygon (px of the final image) into a supersampled canvas."""
    _fill(img, np.asarray(poly_px, float), bgr)


def sheet_corners(centre_px=(640.0, 360.0), width_px=300.0, aspect=297.0 / 210.0, angle_deg=10.0,
                  persp=0.0):
    """Return (4, 2) corners of a sheet seen roughly from above (optional keystone)."""
    w, h = width_px / 2.0, width_px * aspect / 2.0
    pts = np.array([[-w * (1 - persp), -h], [w * (1 - persp), -h], [w, h], [-w, h]])
    a = np.deg2rad(angle_deg)
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    return pts @ rot.T + np.asarray(centre_px)


def project_sheet(rvec, tvec_m, size_m=(0.210, 0.297)):
    """Return (4, 2) image corners of a sheet (its own frame at its centre) seen by ``K``."""
    w, h = size_m[0] / 2.0, size_m[1] / 2.0
    obj = np.array([[-w, -h, 0.0], [w, -h, 0.0], [w, h, 0.0], [-w, h, 0.0]])
    pts, _ = cv2.projectPoints(obj, np.asarray(rvec, float), np.asarray(tvec_m, float), K, None)
    return pts.reshape(4, 2)
