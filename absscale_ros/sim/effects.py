"""
Camera effects on a rendered frame: motion blur, auto-exposure drift, white balance,
vignetting, sensor noise. The shader's output is display-encoded (gamma 2): gains are applied
as the square root of the linear gain, which is exact for a power law.
"""
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core.types import CameraModel
from absscale_ros.sim import camera as simcam
from absscale_ros.sim.render import BLOCK, F32, FloatArray

MAX_BLUR_SAMPLES = 4  # per level: at most 4 + 4 remaps for 16 samples
BLUR_SPACING_PX = 2.5  # sub-exposure samples at most this far apart along a streak
SHORT_STREAK_PX = 8.0  # shorter streaks: line-kernel filters, one per image tile
BLUR_TILES = 3  # tiles per image side for short streaks (the streak field varies slowly)
NOISE_MARGIN = 64  # noise bank border: each frame reads the bank at a random offset


@dataclass(frozen=True)
class EffectsConfig:
    """Per-scene camera behaviour."""

    exposure_s: float = 0.008  # shutter time: sets the motion-blur length
    brightness_target: float = 118.0  # auto-exposure aims the mean display value here
    read_noise_dn: float = 1.2  # noise std at black, 8-bit display units
    shot_noise: float = 0.035  # noise variance per display unit of signal
    vignetting: float = 0.22  # linear fall-off at the image corners

    def __post_init__(self) -> None:
        if not 0.0 < self.exposure_s < 0.05:
            raise ValueError(f'exposure_s must be in (0, 0.05) s, got {self.exposure_s}')
        if not 0.0 <= self.vignetting < 0.8:
            raise ValueError(f'vignetting must be in [0, 0.8), got {self.vignetting}')


class CameraEffects:
    """Stateful (auto-exposure) effects for one video; deterministic given the rng."""

    def __init__(self, camera: CameraModel, cfg: EffectsConfig, rng: np.random.Generator) -> None:
        self._cfg = cfg
        self._rng = rng
        self._camera = camera
        h, w = camera.height, camera.width
        v, u = np.mgrid[0:h, 0:w].astype(np.float32)
        r2 = ((u - camera.K[0, 2]) ** 2 + (v - camera.K[1, 2]) ** 2) / (0.25 * (w * w + h * h))
        # Linear fall-off ~ cos^4 of the field angle, as a smooth radial polynomial.
        vignette = np.sqrt(1.0 - cfg.vignetting * r2 * (0.7 + 0.3 * r2)).astype(np.float32)
        self._vignette = cv2.merge([vignette] * 3)
        # Gaussian noise is costly to draw per frame: draw two large fields once and read each
        # frame at a random offset (sample independent across a frame and between frames).
        m = NOISE_MARGIN
        self._noise_bank = rng.standard_normal((2, h + m, w + m, 3), dtype=np.float32)
        gh, gw = h // BLOCK + 1, w // BLOCK + 1
        self._grid_px = simcam.pixel_grid(w, h, BLOCK).reshape(gh, gw, 2).astype(np.float32)
        self._u, self._v = u, v
        self._gain = 1.0
        self._drift = rng.uniform(0.0, 2.0 * np.pi, size=5)
        self._drift_hz = rng.uniform(0.05, 0.2, size=5)

    def motion_blur(self, colour: F32, grid_points_world_m: F32, T_start: FloatArray,
                    T_end: FloatArray) -> tuple[F32, float]:
        """
        Average the image along each pixel's motion during the exposure.

        :param grid_points_world_m: (Hg, Wg, 3) surface points behind the 4-px grid.
        :param T_start: T_world_cam at the start of the exposure; ``T_end`` at its end.
        :returns: blurred image and the longest streak, px.
        """
        ends = [self._project(grid_points_world_m, T) - self._grid_px for T in (T_start, T_end)]
        streak = ends[1] - ends[0]
        finite = np.isfinite(streak).all(axis=2)
        length = float(np.max(np.linalg.norm(streak[finite], axis=1))) if finite.any() else 0.0
        if length < 1.0:  # sub-pixel streaks do not show
            return colour, length
        if length < SHORT_STREAK_PX:
            return _tiled_line_blur(colour, streak, finite), length
        n = int(min(MAX_BLUR_SAMPLES ** 2, np.ceil(length / BLUR_SPACING_PX) + 1))
        h, w = self._camera.height, self._camera.width
        flows = [cv2.resize(np.nan_to_num(e[:-1, :-1]), (w, h), interpolation=cv2.INTER_LINEAR)
                 for e in ends]
        # A point seen at p mid-exposure is at p + f(s) at sub-time s, so at that time pixel p
        # shows what the mid-exposure image has at p - f(s); f runs linearly start -> end.
        start = [self._u - flows[0][..., 0], self._v - flows[0][..., 1]]
        delta = [flows[0][..., c] - flows[1][..., c] for c in range(2)]
        if n <= MAX_BLUR_SAMPLES:
            return self._box(colour, start, delta, n, 1.0 / (n - 1)), length
        # Long streaks: a box of a samples spaced a * s, then a box of a samples spaced s on its
        # result, gives a * a samples evenly spaced by s for 2a remaps (flow locally uniform).
        a = int(np.ceil(np.sqrt(n)))
        s = 1.0 / (a * a - 1)
        coarse = self._box(colour, start, delta, a, a * s)
        return self._box(coarse, [self._u, self._v], delta, a, s), length

    def _box(self, image: F32, start: list[F32], delta: list[F32], count: int,
             spacing: float) -> F32:
        """Mean of ``count`` remaps at ``start + k * spacing * delta``, k = 0..count-1."""
        acc = np.zeros_like(image)
        for k in range(count):
            mx, my = (cv2.scaleAdd(delta[c], k * spacing, start[c]) for c in range(2))
            acc += cv2.remap(image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        return acc * np.float32(1.0 / count)

    def _project(self, points_world_m: F32, T_world_cam: FloatArray) -> F32:
        shape = points_world_m.shape
        R, t = T_world_cam[:3, :3], T_world_cam[:3, 3]
        pts_cam = (points_world_m.reshape(-1, 3).astype(np.float64) - t) @ R
        return simcam.project(self._camera, pts_cam).astype(np.float32).reshape(*shape[:2], 2)

    def expose(self, colour: F32, t_s: float) -> tuple[npt.NDArray[np.uint8], float]:
        """
        Auto-exposure with lag and drift, white balance drift, vignetting, noise -> BGR uint8.

        :param colour: (H, W, 3) RGB display-encoded, 8-bit scale.
        :returns: (H, W, 3) uint8 BGR image and the exposure gain used (linear).
        """
        cfg = self._cfg
        mean = float(cv2.mean(colour[::8, ::8])[:3][1]) + 1e-3
        # Display value ~ sqrt(gain * radiance): this gain would hit the target; the camera
        # moves only 30 % of the way there (in log) per frame, so exposure lags.
        wanted = (cfg.brightness_target / mean) ** 2
        self._gain *= (wanted / self._gain) ** 0.3
        s = np.sin(self._drift + 2.0 * np.pi * self._drift_hz * t_s)
        gain = self._gain * np.exp(0.10 * s[0])  # metering jitter
        wb = np.array([1.0 + 0.04 * s[1], 1.0 + 0.015 * s[2], 1.0 + 0.05 * s[3]])
        scale = (*np.sqrt(gain * wb).tolist(), 0.0)
        h, w = colour.shape[:2]
        k, dy, dx = (int(v) for v in self._rng.integers(0, [2, NOISE_MARGIN, NOISE_MARGIN]))
        out = np.empty((h, w, 3), np.uint8)
        for r in range(0, h, 48):  # row bands: the arithmetic stays in the CPU cache
            band = slice(r, min(r + 48, h))
            img = cv2.multiply(cv2.multiply(colour[band], self._vignette[band]), scale)
            unit = self._noise_bank[k, dy + band.start:dy + band.stop, dx:dx + w]
            out[band] = cv2.cvtColor(self._noise(img, unit), cv2.COLOR_RGB2BGR)
        return out, float(gain)

    def _noise(self, img: F32, unit: F32) -> npt.NDArray[np.uint8]:
        """Shot + read noise, std sqrt(shot * value + read^2) display units; ``unit``: N(0, 1)."""
        # OpenCV takes a bare float as (v, 0, 0, 0): give every channel its value.
        shot = (self._cfg.shot_noise,) * 3 + (0.0,)
        read = (self._cfg.read_noise_dn ** 2,) * 3 + (0.0,)
        var = cv2.add(cv2.multiply(img, shot), read)
        noise = cv2.multiply(unit, cv2.sqrt(cv2.max(var, 0.0)))
        return cv2.add(img, noise, dtype=cv2.CV_8U)


def _tiled_line_blur(colour: F32, streak: F32, finite: npt.NDArray[np.bool_]) -> F32:
    """
    Short streaks: per tile of the image, one line kernel along the tile's streaks.

    :param streak: (Hg, Wg, 2) streak vectors at the grid points, px; ``finite`` marks valid.
    """
    h, w = colour.shape[:2]
    gh, gw = streak.shape[:2]
    out = np.empty_like(colour)
    pad = int(SHORT_STREAK_PX) // 2 + 2
    for i in range(BLUR_TILES):
        for j in range(BLUR_TILES):
            y0, y1 = h * i // BLUR_TILES, h * (i + 1) // BLUR_TILES
            x0, x1 = w * j // BLUR_TILES, w * (j + 1) // BLUR_TILES
            gy, gx = slice(gh * i // BLUR_TILES, gh * (i + 1) // BLUR_TILES + 1), \
                slice(gw * j // BLUR_TILES, gw * (j + 1) // BLUR_TILES + 1)
            ok = finite[gy, gx]
            if not ok.any():
                out[y0:y1, x0:x1] = colour[y0:y1, x0:x1]
                continue
            py0, py1, px0, px1 = max(y0 - pad, 0), min(y1 + pad, h), max(x0 - pad, 0), \
                min(x1 + pad, w)
            blurred = _line_blur(colour[py0:py1, px0:px1], streak[gy, gx][ok])
            out[y0:y1, x0:x1] = blurred[y0 - py0:y1 - py0, x0 - px0:x1 - px0]
    return out


def _line_blur(colour: F32, streaks_px: F32) -> F32:
    """
    Blur by one line kernel along the principal direction of ``streaks_px``.

    :param streaks_px: (N, 2) streak vectors (start to end of exposure), px.
    """
    # Principal direction and RMS length of the streaks (signs do not matter for a line).
    tensor = streaks_px.T.astype(np.float64) @ streaks_px / len(streaks_px)
    values, vectors = np.linalg.eigh(tensor)
    length, direction = float(np.sqrt(max(values[1], 0.0))), vectors[:, 1]
    if length < 0.5:
        return colour
    half = int(np.ceil(length / 2.0)) + 1
    kernel = np.zeros((2 * half + 1, 2 * half + 1), np.float32)
    for s in np.linspace(-0.5, 0.5, 17):  # splat the segment bilinearly
        x, y = half + s * length * direction[0], half + s * length * direction[1]
        x0, y0 = int(np.floor(x)), int(np.floor(y))
        fx, fy = x - x0, y - y0
        kernel[y0, x0] += (1 - fx) * (1 - fy)
        kernel[y0, x0 + 1] += fx * (1 - fy)
        kernel[y0 + 1, x0] += (1 - fx) * fy
        kernel[y0 + 1, x0 + 1] += fx * fy
    kernel /= kernel.sum()
    return cv2.filter2D(colour, -1, kernel, borderType=cv2.BORDER_REFLECT)
