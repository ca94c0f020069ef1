"""
Cube shape check: image vertices must be where a cube seen through the camera puts them.

A face whose side is cut by an occluder, or a box of a cube colour beside the cube, gives
corners that are not cube vertices; a wrong vertex gives a wrong scale downstream. Every
whole face is a square, so its four corners fix the cube's pose (IPPE on a square, both of
its solutions; the cube lies behind the face as seen from the camera). A pose is believed when
another whole face found outlines a side face that the posed cube shows, or lies within one,
or a face seen edge-on (a strip along a side) has its far side where the pose puts that face's
far corners: a face cut by a post looks like a square seen obliquely, but the cube posed
on it does not show its neighbours where they are. A vertex is kept only when every believed
pose puts it within ``tol_frac`` of the posing face's size of a projected cube vertex; a poor
pose then costs a true vertex rather than adding a wrong one.
"""
import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core import lines

Array = npt.NDArray[np.float64]
Posed = tuple[Array, float]  # (8, 2) projected cube vertices, their tolerance px
# The unit square in the order IPPE_SQUARE wants (x right, y up in the model plane).
_SQUARE = np.array([[-0.5, 0.5, 0.0], [0.5, 0.5, 0.0], [0.5, -0.5, 0.0], [-0.5, -0.5, 0.0]])
# Side faces of the cube posed on a face (corners 0-3, the four behind it 4-7), each ordered
# like the posing face as seen from outside: shared edges run the other way.
_SIDES = ((1, 0, 4, 5), (2, 1, 5, 6), (3, 2, 6, 7), (0, 3, 7, 4))
_FACES = np.array([(0, 1, 2, 3), *_SIDES])  # the posing face and its sides, (5, 4)
MIN_IOU = 0.4  # a detected face and a face the posed cube shows agree above this overlap
MIN_INSIDE = 0.8  # ... or when this share of the detected face lies within the shown face
# A strip agrees with a pose when the far corners of its face lie within this many strip widths
# of its measured far side: a face seen nearly square-on poses its neighbours' depth loosely.
STRIP_SLACK = 3.0


def default_K(shape: tuple[int, ...], focal_frac: float) -> Array:
    """Return a pinhole K with focal ``focal_frac`` x the larger image side, centred."""
    h, w = shape[:2]
    f = focal_frac * max(h, w)
    return np.array([[f, 0.0, 0.5 * (w - 1)], [0.0, f, 0.5 * (h - 1)], [0.0, 0.0, 1.0]])


def cube_projections(corners_px: Array, K: Array) -> list[Array]:
    """
    Return per pose solution of one face the (8, 2) projected cube vertices: the face's own
    four corners (in ``corners_px`` order) then the four behind them.
    """
    ok, rvecs, tvecs, _ = cv2.solvePnPGeneric(
        _SQUARE, corners_px.astype(np.float64), K, None, flags=cv2.SOLVEPNP_IPPE_SQUARE)
    out = []
    for rvec, tvec in zip(rvecs, tvecs) if ok else ():
        R, _ = cv2.Rodrigues(rvec)
        cam_z = float(-(R.T @ tvec.ravel())[2])  # camera centre in the face frame, z
        if cam_z == 0.0:
            continue
        behind = _SQUARE - [0.0, 0.0, np.sign(cam_z)]  # away from the camera
        cam = np.concatenate([_SQUARE, behind]) @ R.T + tvec.ravel()
        if (cam[:, 2] <= 1e-6).any():
            continue
        proj = cam @ K.T
        out.append(proj[:, :2] / proj[:, 2:])
    return out


def _signed_areas(polys: Array) -> Array:
    """Return the (N,) signed areas of (N, K, 2) polygons (shoelace)."""
    x, y = polys[..., 0], polys[..., 1]
    nxt = (np.arange(x.shape[-1]) + 1) % x.shape[-1]  # np.roll by -1, cheaper
    return 0.5 * (x * y[..., nxt] - y * x[..., nxt]).sum(axis=-1)


def shown_sides(proj: Array) -> list[npt.NDArray[np.float32]]:
    """Return the convex outlines of the side faces that the posed cube ``proj`` shows."""
    polys = proj[_FACES]  # the posing face, then the side faces
    areas = _signed_areas(polys)
    return [cv2.convexHull(poly.astype(np.float32))
            for poly, a in zip(polys[1:], areas[1:]) if a * areas[0] > 0.0]


def agrees(shown: list[npt.NDArray[np.float32]], found: npt.NDArray[np.float32]) -> bool:
    """
    Return True when the convex outline ``found`` of a whole face outlines one of the
    ``shown`` side faces, or lies within one (the visible part of a face an occluder cuts).
    """
    area = cv2.contourArea(found)
    for poly in shown:
        inter = cv2.intersectConvexConvex(poly, found)[0]
        iou = inter / max(cv2.contourArea(poly) + area - inter, 1e-9)
        if iou >= MIN_IOU or inter >= MIN_INSIDE * area:
            return True
    return False


def explained(vertices_px: Array, posing: list[int], polygons: list[Array], thin: list[bool],
              mute: list[bool], Ks: list[Array], tol_frac: float,
              pose_corners: dict[int, Array] | None = None
              ) -> tuple[npt.NDArray[np.bool_], Posed | None]:
    """
    Return (V,) True for vertices that every believed single-face cube pose explains, with
    the camera of ``Ks`` (several when the focal length is unknown) that explains the most,
    and ((8, 2) projected cube, its tolerance px) of the believed pose that explains the most
    (or None).

    :param vertices_px: (V, 2) assembled cube vertices.
    :param posing: indices into ``polygons`` of the faces that pose the cube (whole faces,
        not seen too obliquely).
    :param polygons: (4, 2) outlines of every face of this cube found (whole or edge-on).
    :param thin: per polygon, True for a face seen edge-on (``cube_strips``).
    :param mute: per polygon, True for a face that cannot make a pose believed (a strip whose
        colour runs on past its side).
    :param tol_frac: largest distance of a vertex from its projected cube vertex, as a
        fraction of the longest side of the face that gave the pose.
    :param pose_corners: posing faces whose pose comes from other corners than their
        outline (a face cut by the image border, completed: ``complete_cut``), with one K.
    :returns: all False and None when no pose is believed.
    """
    best: tuple[npt.NDArray[np.bool_], Posed | None] = (np.zeros(len(vertices_px), bool), None)
    for K in Ks:
        keep, proj = _explained(vertices_px, posing, polygons, thin, mute, K, tol_frac,
                                pose_corners or {})
        if keep.sum() > best[0].sum():
            best = keep, proj
    return best


def _explained(vertices_px: Array, posing: list[int], polygons: list[Array], thin: list[bool],
               mute: list[bool], K: Array, tol_frac: float, pose_corners: dict[int, Array]
               ) -> tuple[npt.NDArray[np.bool_], Posed | None]:
    keep, best, best_n = None, None, -1  # type: ignore[var-annotated]
    hulls = [cv2.convexHull(p.astype(np.float32)) for p in polygons]
    for f in posing:
        corners = pose_corners.get(f, polygons[f])
        side = float(np.hypot(*(corners - corners[[1, 2, 3, 0]]).T).max())
        tol = max(3.0, tol_frac * side)
        for proj in cube_projections(corners, K):
            shown = shown_sides(proj)
            if not any(strip_far_corners(proj, polygons[g], tol, STRIP_SLACK) is not None
                       if thin[g]
                       else agrees(shown, hulls[g]) for g in range(len(polygons))
                       if g != f and not mute[g]):
                continue
            near = np.hypot(*(vertices_px[:, None, :] - proj[None, :, :]).transpose(2, 0, 1))
            ok = near.min(axis=1) < tol
            keep = ok if keep is None else keep & ok
            if ok.sum() > best_n:
                best, best_n = (proj, tol), int(ok.sum())
    return (np.zeros(len(vertices_px), dtype=bool) if keep is None else keep), best


def complete_cut(corners_px: Array, side_lines: Array, cut: int, K: Array) -> Array | None:
    """
    Return the (4, 2) corners of a square face the image border cuts along side ``cut``
    (its corners ``cut`` and ``cut + 1`` lie on the border), from what is seen: the whole
    side between its other two corners A, B and the directions of the two sides leaving
    them (parallel in 3D: their vanishing point gives their direction, the side A B's plane
    through the camera the one perpendicular to it; ``sheet_stub.far_corners``). Each far
    corner is the one on the seen part's side of its corner; None when either is missing.
    """
    from absscale_ros.core import sheet_stub  # (the same construction: a stub sheet's side)
    a, b = (cut + 2) % 4, (cut + 3) % 4
    out = corners_px.copy()
    for near, other, l_near, l_other, far in ((a, b, side_lines[(cut + 1) % 4],
                                               side_lines[b], (cut + 1) % 4),
                                              (b, a, side_lines[b], side_lines[(cut + 1) % 4],
                                               cut)):
        towards = corners_px[far] - corners_px[near]
        ends = [p for p in sheet_stub.far_corners(corners_px[near], corners_px[other], l_near,
                                                  l_other, K, 1.0)
                if (p - corners_px[near]) @ towards > 0.0]
        if not ends:
            return None
        out[far] = ends[0]
    return out


def strip_far_corners(proj: Array, strip: Array, tol: float, slack: float) -> Array | None:
    """
    Return the (2, 2) far corners that the posed cube ``proj`` (8, 2) gives a face seen
    edge-on, ``strip`` = [c0, far0, far1, c1] (its far corners measured along the shared side's
    normal only), or None when the pose does not fit the strip: c0 and c1 each within ``tol``
    of a cube vertex, and the face's far corners near the measured far side (within ``slack``
    times the strip's width, 3 px at least) and beside the shared side, not beyond it.
    """
    c0, far0, far1, c1 = strip
    d0, d1 = (np.hypot(*(proj - c).T) for c in (c0, c1))
    i0, i1 = int(np.argmin(d0)), int(np.argmin(d1))
    if max(d0[i0], d1[i1]) > tol:
        return None
    best = None
    for face in ((0, 1, 2, 3),) + _SIDES + ((4, 5, 6, 7),):
        if i0 not in face or i1 not in face:
            continue
        k0, k1 = face.index(i0), face.index(i1)
        if (k1 - k0) % 4 not in (1, 3):
            continue
        step = 1 if (k1 - k0) % 4 == 1 else -1  # far corners: the face's other two
        far = proj[[face[(k0 - step) % 4], face[(k1 + step) % 4]]]
        cost = np.hypot(*(far[0] - far0)) + np.hypot(*(far[1] - far1))
        if best is None or cost < best[0]:
            best = (cost, far)
    if best is None:
        return None
    far = best[1]
    far_line = lines.cross3(np.array([*far0, 1.0]), np.array([*far1, 1.0]))
    far_line /= max(float(np.hypot(*far_line[:2])), 1e-12)
    width = max(np.hypot(*(far0 - c0)), np.hypot(*(far1 - c1)))
    along = (far - c0) @ (c1 - c0) / max(float((c1 - c0) @ (c1 - c0)), 1e-9)
    if np.abs(far @ far_line[:2] + far_line[2]).max() > max(3.0, slack * width):
        return None
    if along.min() < -0.3 or along.max() > 1.3:
        return None
    return far


def complete_strip(proj: Array, tol: float, strip: Array) -> Array:
    """
    Return the (4, 2) outline of a face seen edge-on, ``strip`` = [c0, far0, far1, c1]: its
    far corners moved to where the posed cube ``proj`` puts them when they lie within half the
    strip's width of its measured far side (``strip_far_corners``), unchanged otherwise.
    """
    far = strip_far_corners(proj, strip, tol, 0.5)
    return strip if far is None else np.array([strip[0], far[0], far[1], strip[3]])
