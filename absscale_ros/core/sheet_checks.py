"""
The sheet detector's tests of a refined candidate: support and contrast, one colour inside and
outside, the sheet's aspect, not a floor tile between grout lines, big enough, and for a
hidden corner something lying on it.
"""
from typing import Callable, TYPE_CHECKING

import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core import lines, sides, targets

if TYPE_CHECKING:
    from absscale_ros.core.detect_sheet import SheetConfig

Array = npt.NDArray[np.float64]
FOCAL_STEPS = 5  # focal lengths tried over ``focal_range`` without intrinsics
ASPECT_STEP_PX = 0.25  # corner shift of the aspect's finite differences
SHADE_FLOOR = 32.0  # brightness floor of the shade-free colour test: dark colours are noisy


def covered(image_bgr: npt.NDArray[np.uint8], corner: Array, inside: Array,
            cfg: 'SheetConfig', outside: Array | None = None) -> bool:
    """
    Return True when something other than the sheet's colour lies on the hidden corner, and
    (with ``outside``, the (4, 3) colours just outside the sides) other than the surface's or
    a blend of the two: a card whose blurred corner looked cut off shows only the blurred
    card and the desk at the corner placed beyond it. A corner beyond the image border is
    not hidden by anything seen (a board the border cuts: a negative row once sliced the
    whole image column as its patch).
    """
    h, w = image_bgr.shape[:2]
    u, v = int(round(corner[0])), int(round(corner[1]))
    if not (0 <= u < w and 0 <= v < h):
        return False
    patch = image_bgr[max(v - 2, 0):min(v + 3, h), max(u - 2, 0):min(u + 3, w)].reshape(-1, 3)
    if not len(patch):
        return False
    colour, ref = np.median(patch, axis=0), np.median(inside, axis=0)
    if outside is not None:  # the nearest blend of the sheet's and the surface's colours
        out = np.median(outside, axis=0)
        step = ref - out
        t = float((colour - out) @ step) / max(float(step @ step), 1e-9)
        ref = out + min(max(t, 0.0), 1.0) * step
    return bool(np.linalg.norm(colour - ref) >= cfg.min_contrast)


def big_enough(outline: Array, shape: tuple[int, ...], cfg: 'SheetConfig') -> bool:
    """Return True when the seen outline (K, 2) covers at least ``min_area_frac`` of the image."""
    area = cv2.contourArea(outline.astype(np.float32))
    return bool(area >= cfg.min_area_frac * shape[0] * shape[1])


def passes(image_bgr: npt.NDArray[np.uint8], refined: sides.Refined, cfg: 'SheetConfig',
           K: Array | None, seen_ends: Array | None = None,
           aspect_tol: float | None = None, dist: Array | None = None,
           note: Callable[[float], None] | None = None) -> bool:
    """
    Apply the support, contrast, one-colour, aspect and floor-tile tests to a refined
    quadrilateral (``seen_ends`` (4, 2, 2): the seen part of each side, default all of it;
    ``aspect_tol``: instead of ``aspect_tolerance``; ``dist``: see ``aspect_error``).
    ``note`` is given the aspect error over its tolerance when the tests before the aspect's
    pass (``sheet_track``).
    """
    corners, supports, steps, inside, outside = refined
    if supports.min() < cfg.min_support or steps.min() < cfg.min_contrast:
        return False  # not a sheet on a different surface all round
    if (inside.max(axis=1) < cfg.min_inside_ratio * outside.max(axis=1)).any():
        return False  # darker than its surface at a side: that side is some other edge
    if not one_colour(inside, cfg.max_inside_spread, cfg.max_saturation, cfg.max_shade):
        return False  # four edges of different things (a table top, its legs, the floor)
    if not one_colour(outside, cfg.max_outside_spread, 1.0, cfg.max_shade):
        return False  # a sheet lies on one surface: wall between table legs, floor below
    err = aspect_error(corners, image_bgr.shape, cfg, K, dist)
    tol = cfg.aspect_floor
    if note is not None or err > cfg.aspect_floor:
        tol = max(tol, aspect_tolerance(corners, cfg, K, dist=dist) if aspect_tol is None
                  else aspect_tol)
    if note is not None:
        note(err / tol)
    if err > tol:
        return False
    return not tile(image_bgr, corners, cfg, seen_ends)


def tile(image_bgr: npt.NDArray[np.uint8], corners: Array, cfg: 'SheetConfig',
         seen_ends: Array | None = None) -> bool:
    """
    Return True when the colour recovers beyond too many sides: a tile between grout. Looked
    for at two reaches: a blurred grout line is wider than the first.
    """
    ends = np.stack([corners, np.roll(corners, -1, axis=0)], axis=1)
    ends = ends if seen_ends is None else seen_ends
    side_px = float(np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1).mean())
    ls = np.array([lines.line_through(a, b, corners.mean(axis=0)) for a, b in ends])
    ridges = sides.ridge_ratio(image_bgr, ls, ends, max(8.0, 0.08 * side_px), reaches=(1.0, 2.0))
    return int((ridges > cfg.ridge_ratio).sum()) > cfg.max_ridges


def aspect_tolerance(corners: Array, cfg: 'SheetConfig', K: Array | None,
                     noise: float = 1.0, cap: float = 1.0, dist: Array | None = None) -> float:
    """
    Return the aspect test's tolerance for refined ``corners`` (4, 2) px (corners ``noise``
    times less sure than sharp ones: up to ``cap`` times ``cfg.aspect_tol``).

    With intrinsics the side ratio is exact up to corner noise, whose effect ranges from a
    fraction of a percent (a big sheet seen from above) to over ten (a small one seen edge-on):
    the tolerance is the ratio change that corner shifts of ``cfg.aspect_corner_px`` (RMS over
    the eight coordinates' independent shifts) cause, within ``cfg.aspect_floor`` (lens
    distortion, paper cut) and ``cfg.aspect_tol``. A fixed 8 % passed a 4:3 board (3 % off
    letter) seen square-on. Without intrinsics: ``cfg.aspect_tol``.
    """
    if K is None or cfg.aspect_corner_px <= 0.0:
        return cfg.aspect_tol * cap
    moved = np.repeat(undistort(corners, K, dist).reshape(1, 8), 9, axis=0)
    moved[1:] += ASPECT_STEP_PX * np.eye(8)  # row 0 as it is, rows 1-8 one coordinate moved
    aspects = lines.rectangle_aspects(moved.reshape(9, 4, 2), K)
    a0, grads = float(aspects[0]), aspects[1:] - aspects[0]
    spread = noise * cfg.aspect_corner_px * float(np.linalg.norm(grads)) / (ASPECT_STEP_PX * a0)
    return float(np.clip(spread, cfg.aspect_floor, cap * cfg.aspect_tol))


def undistort(corners_px: Array, K: Array, dist: Array | None) -> Array:
    """
    Return (N, 2) pixel positions without lens distortion (``dist``: OpenCV coefficients, or
    None for none). Near the image border a barrel lens moves a 4:3 board's aspect 2 % towards
    letter's: the test is on where a pinhole camera would see the corners.
    """
    if dist is None or not np.any(dist):
        return corners_px
    pts = np.asarray(corners_px, np.float64).reshape(-1, 1, 2)
    return cv2.undistortPoints(pts, K, np.asarray(dist, np.float64), P=K).reshape(-1, 2)


def aspect_ok(corners: Array, shape: tuple[int, ...], cfg: 'SheetConfig', K: Array | None,
              tol: float, dist: Array | None = None) -> bool:
    """Return True when the rectangle imaged as ``corners`` has the sheet's aspect (+-tol)."""
    return aspect_error(corners, shape, cfg, K, dist) <= tol


def aspect_error(corners: Array, shape: tuple[int, ...], cfg: 'SheetConfig',
                 K: Array | None, dist: Array | None = None) -> float:
    """
    Return the relative deviation of the imaged rectangle's aspect from the nearest configured
    sheet's (``cfg.models()``); with intrinsics, after undoing lens distortion ``dist``.

    Without intrinsics, the smallest deviation over the focal lengths of ``cfg.focal_range``
    (0 when the aspect passes the sheet's within it): a focal length estimated from the
    quadrilateral's own vanishing points is unstable under mild perspective (real A4 pages
    measured 5-10 % off with it, within 1.3 % at the camera's focal length).
    """
    h, w = shape[:2]
    centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    if K is not None:
        aspects = [lines.rectangle_aspect(undistort(corners, K, dist), K, 0.0, centre)]
    else:
        aspects = []
        for frac in np.linspace(cfg.focal_range[0], cfg.focal_range[1], FOCAL_STEPS):
            f = frac * max(h, w)
            K_f = np.array([[f, 0.0, centre[0]], [0.0, f, centre[1]], [0.0, 0.0, 1.0]])
            aspects.append(lines.rectangle_aspect(corners, K_f, f, centre))
    best = np.inf
    for model in cfg.models():
        if min(aspects) <= model.aspect <= max(aspects):
            return 0.0
        best = min(best, min(abs(a / model.aspect - 1.0) for a in aspects))
    return float(best)


def aspect_errors(corners: Array, cfg: 'SheetConfig', K: Array, dist: Array | None = None
                  ) -> Array:
    """``aspect_error`` with intrinsics of many quadrilaterals (M, 4, 2) at once: (M,), bit for
    bit its values."""
    flat = undistort(corners.reshape(-1, 2), K, dist).reshape(-1, 4, 2)
    with np.errstate(divide='ignore', invalid='ignore'):  # (degenerate rough corners)
        aspects = lines.rectangle_aspects_each(flat, K)
        # (``aspect_error``'s 0 where an aspect equals the model's is |a / m - 1| there too)
        return np.min([np.abs(aspects / m.aspect - 1.0) for m in cfg.models()], axis=0)


def best_model(corners: Array, shape: tuple[int, ...], cfg: 'SheetConfig', K: Array | None
               ) -> targets.SheetModel:
    """
    Return the configured sheet model whose aspect the imaged rectangle fits best (without
    intrinsics: at the focal length guess ``cfg.focal_frac``).
    """
    models = cfg.models()
    if len(models) == 1:
        return models[0]
    h, w = shape[:2]
    centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    f = cfg.focal_frac * max(h, w)
    K_ = K if K is not None else np.array([[f, 0.0, centre[0]], [0.0, f, centre[1]],
                                           [0.0, 0.0, 1.0]])
    aspect = lines.rectangle_aspect(corners, K_, f, centre)
    return min(models, key=lambda m: abs(aspect / m.aspect - 1.0))


def one_colour(bgr: Array, max_spread: float, max_saturation: float,
               max_shade: float = 1.0) -> bool:
    """
    Return True when (4, 3) side colours are one colour, no more saturated than given.

    ``max_shade`` > 1: one surface in light and shadow alike. A shadow scales a colour (its
    hue stays), so the spread is measured on the colours brought to the median's brightness
    and the brightnesses may differ up to this factor (a hand's or the camera's shadow across
    a page, real photographs); 1 compares the colours as they are.
    """
    ref = np.median(bgr, axis=0)
    level = max(float(ref.max()), 1.0)
    if max_shade > 1.0:
        lv = np.maximum(bgr.max(axis=1), SHADE_FLOOR)
        if float(lv.max() / lv.min()) > max_shade:
            return False
        bgr = bgr * (max(level, SHADE_FLOOR) / lv)[:, None]
    spread = float(np.linalg.norm(bgr - ref, axis=1).max())
    return spread <= max_spread * level and \
        float(ref.max() - ref.min()) <= max_saturation * level
