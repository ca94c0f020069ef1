"""
Procedural, tileable texture patterns (display-encoded, gamma 2, values in [0, 1]).

Each generator draws from the rng it is given and returns a (TILE, TILE, 3) float32 tile that
repeats seamlessly; ``textures.atlas`` packs them with their mip levels.
"""
import cv2
import numpy as np
import numpy.typing as npt

TILE = 1024  # level-0 texels per tile side (a power of two: every mip level tiles exactly)
F32 = npt.NDArray[np.float32]


def _noise(rng: np.random.Generator, cells_x: int, cells_y: int | None = None) -> F32:
    """Tileable value noise in [0, 1] on a TILE x TILE grid (bicubic between random cells)."""
    cy = cells_x if cells_y is None else cells_y
    grid = rng.random((cy, cells_x)).astype(np.float32)
    pad = 2
    big = np.pad(grid, pad, mode='wrap')
    sx, sy = TILE // cells_x, TILE // cy
    up = cv2.resize(big, (big.shape[1] * sx, big.shape[0] * sy), interpolation=cv2.INTER_CUBIC)
    return up[pad * sy:pad * sy + TILE, pad * sx:pad * sx + TILE]


def _fractal(rng: np.random.Generator, first: int, last: int, gain: float = 0.6) -> F32:
    """Sum of noise octaves from ``first`` to ``last`` cells, normalised to [0, 1]."""
    out = np.zeros((TILE, TILE), np.float32)
    amp, total, cells = 1.0, 0.0, first
    while cells <= last:
        out += amp * _noise(rng, cells)
        total += amp
        amp *= gain
        cells *= 2
    out /= total
    return (out - out.min()) / max(float(np.ptp(out)), 1e-6)


def _grid_cells(pitch_x: int, pitch_y: int, stagger: bool) -> tuple[npt.NDArray[np.int64], ...]:
    """Per texel: brick/tile column and row index, and distance to the nearest joint, texels."""
    y, x = np.mgrid[0:TILE, 0:TILE]
    row = y // pitch_y
    xs = x + (row % 2) * (pitch_x // 2) * int(stagger)
    col = (xs // pitch_x) % (TILE // pitch_x)
    joint = np.minimum(np.minimum(xs % pitch_x, pitch_x - 1 - xs % pitch_x),
                       np.minimum(y % pitch_y, pitch_y - 1 - y % pitch_y))
    return col, row, joint


def _rgb(gray: F32, colour: tuple[float, float, float]) -> F32:
    return gray[..., None] * np.asarray(colour, np.float32)


def _plaster(rng: np.random.Generator) -> F32:
    g = 0.82 + 0.10 * _fractal(rng, 4, 64) + 0.06 * _noise(rng, 512) + 0.04 * _noise(rng, 256)
    return _rgb(g, (1.0, 1.0, 1.0))


def _ceiling(rng: np.random.Generator) -> F32:
    _, _, joint = _grid_cells(256, 256, False)
    g = 0.86 + 0.05 * _fractal(rng, 8, 128) + 0.06 * _noise(rng, 512) - 0.25 * (joint < 3)
    return _rgb(g, (1.0, 1.0, 1.0))


def _wallpaper(rng: np.random.Generator) -> F32:
    y, x = np.mgrid[0:TILE, 0:TILE].astype(np.float32)
    motif = np.abs(np.sin(np.pi * x / 64.0)) * np.abs(np.sin(np.pi * y / 64.0 + np.pi * x / 128))
    g = 0.72 + 0.14 * motif + 0.08 * _fractal(rng, 8, 256)
    return _rgb(g, (1.0, 0.96, 0.88))


def _planks(rng: np.random.Generator, base: float, spread: float) -> F32:
    col, row, _ = _grid_cells(512, 64, True)
    tone = rng.uniform(-spread, spread, size=(TILE // 64 + 1, 3))[row, col % 3]
    grain = _noise(rng, 8, 256) * 0.6 + 0.4 * _noise(rng, 32, 512)
    y, x = np.mgrid[0:TILE, 0:TILE]
    gap = ((y % 64) < 2) | (((x + (y // 64 % 2) * 256) % 512) < 2)
    g = base + tone + 0.16 * grain - 0.3 * gap
    return _rgb(g.astype(np.float32), (1.0, 0.80, 0.60))


def _tiles(rng: np.random.Generator) -> F32:
    col, row, joint = _grid_cells(256, 256, False)
    tone = rng.uniform(-0.06, 0.06, size=(4, 4))[row % 4, col % 4]
    g = 0.74 + tone + 0.10 * _fractal(rng, 16, 512) - 0.35 * (joint < 4)
    return _rgb(g.astype(np.float32), (0.95, 0.93, 0.88))


def _carpet(rng: np.random.Generator) -> F32:
    g = 0.45 + 0.25 * _noise(rng, 512) + 0.2 * _fractal(rng, 8, 128)
    return _rgb(g, (0.75, 0.78, 0.95))


def _laminate(rng: np.random.Generator) -> F32:
    g = 0.80 + 0.05 * _noise(rng, 16, 256) + 0.04 * _noise(rng, 512)
    return _rgb(g, (1.0, 1.0, 0.98))


def _cardboard(rng: np.random.Generator) -> F32:
    g = 0.70 + 0.12 * _fractal(rng, 8, 512)
    out = _rgb(g, (0.85, 0.68, 0.48))
    for _ in range(12):  # printed labels and logos: strong corners for feature detectors
        x0, y0 = rng.integers(0, TILE - 160, size=2)
        w, h = rng.integers(30, 160, size=2)
        out[y0:y0 + h, x0:x0 + w] = rng.uniform(0.1, 0.9, size=3)
    return out


def _books(rng: np.random.Generator) -> F32:
    out = np.empty((TILE, TILE, 3), np.float32)
    shade = 0.8 + 0.2 * _noise(rng, 64, 8)
    for y0 in range(0, TILE, 256):  # shelves
        x = 0
        while x < TILE:
            w = int(rng.integers(16, 48))
            h = int(rng.integers(150, 240))
            out[y0:y0 + 256, x:x + w] = 0.15
            out[y0 + 256 - h:y0 + 250, x:x + w - 2] = rng.uniform(0.2, 0.95, size=3)
            x += w
        out[y0 + 250:y0 + 256] = 0.5
    return out * shade[..., None]


def _bricks(rng: np.random.Generator) -> F32:
    col, row, joint = _grid_cells(64, 32, True)
    tone = rng.uniform(0.75, 1.1, size=(TILE // 32, TILE // 64))[row, col]
    g = tone * (0.85 + 0.15 * _noise(rng, 256)) * (0.85 + 0.15 * _fractal(rng, 8, 64))
    out = _rgb(g.astype(np.float32), (0.75, 0.42, 0.32))
    mortar = (joint < 3)[..., None]
    return np.where(mortar, np.float32(0.72) + 0.1 * _noise(rng, 512)[..., None], out)


def _concrete(rng: np.random.Generator) -> F32:
    _, _, joint = _grid_cells(512, 256, False)
    g = 0.62 + 0.18 * _fractal(rng, 4, 256) + 0.03 * _noise(rng, 512)
    holes = _noise(rng, 128) > 0.93
    g = g - 0.25 * holes - 0.2 * (joint < 2)
    return _rgb(_cracks(rng, g.astype(np.float32), 12, 0.25), (0.95, 0.95, 0.92))


def _grass(rng: np.random.Generator) -> F32:
    blades = _noise(rng, 512, 128) * 0.5 + 0.5 * _noise(rng, 256)
    patches = _fractal(rng, 4, 64)
    g = 0.35 + 0.45 * blades
    out = _rgb(g, (0.45, 0.75, 0.30))
    dry = _rgb(g, (0.75, 0.70, 0.40))
    w = np.clip((patches - 0.55) * 4.0, 0.0, 1.0)[..., None]
    return out * (1 - w) + dry * w


def _cracks(rng: np.random.Generator, g: F32, count: int, shade: float) -> F32:
    """Dark random-walk cracks: sharp, world-fixed features at every distance."""
    out = g.copy()
    for _ in range(count):
        p = rng.uniform(0, TILE, 2)
        heading = rng.uniform(0, 2 * np.pi)
        pts = [p.copy()]
        for _ in range(int(rng.integers(8, 30))):
            heading += rng.normal(0.0, 0.5)
            p = p + rng.uniform(6, 20) * np.array([np.cos(heading), np.sin(heading)])
            pts.append(p.copy())
        poly = np.round(np.array(pts)).astype(np.int32) % TILE  # stays inside; wraps jump
        cv2.polylines(out, [poly], False, float(shade), int(rng.integers(1, 4)))
    return out


def _asphalt(rng: np.random.Generator) -> F32:
    g = 0.40 + 0.16 * _fractal(rng, 4, 64) + 0.06 * (_noise(rng, 512) - 0.5)
    g = g + 0.07 * (_noise(rng, 256) > 0.85)
    patches = _noise(rng, 8) > 0.7  # repaired patches: darker, with sharp borders
    g = np.where(patches, g * 0.8, g).astype(np.float32)
    return _rgb(_cracks(rng, g, 25, 0.15), (1.0, 1.0, 1.0))


def _pavers(rng: np.random.Generator) -> F32:
    col, row, joint = _grid_cells(128, 64, True)
    tone = rng.uniform(0.8, 1.1, size=(TILE // 64, TILE // 128))[row, col]
    g = tone * (0.62 + 0.12 * _noise(rng, 256)) - 0.3 * (joint < 3)
    return _rgb(g.astype(np.float32), (0.85, 0.78, 0.72))


def _paper(rng: np.random.Generator) -> F32:
    return _rgb(0.985 + 0.012 * _noise(rng, 512), (1.0, 1.0, 1.0))


def _paint(rng: np.random.Generator) -> F32:
    # Painted plywood: faint grain, the colour comes from the material tint.
    return _rgb(0.93 + 0.04 * _noise(rng, 16, 512) + 0.03 * _noise(rng, 256), (1.0, 1.0, 1.0))


def _window(rng: np.random.Generator) -> F32:
    y = np.mgrid[0:TILE, 0:TILE][0].astype(np.float32) / TILE
    g = 0.25 + 0.2 * np.abs(np.sin(np.pi * 2 * y)) + 0.15 * _fractal(rng, 4, 32)
    _, _, joint = _grid_cells(256, 512, False)
    g = np.where(joint < 12, 0.8, g)
    return _rgb(g.astype(np.float32), (0.75, 0.85, 1.0))


def _foliage(rng: np.random.Generator) -> F32:
    g = 0.2 + 0.55 * _noise(rng, 256) * _fractal(rng, 16, 128)
    return _rgb(g.astype(np.float32), (0.45, 0.8, 0.35))


TEXTURES = {
    'plaster': _plaster, 'ceiling': _ceiling, 'wallpaper': _wallpaper,
    'parquet': lambda rng: _planks(rng, 0.62, 0.08),
    'wood_dark': lambda rng: _planks(rng, 0.42, 0.04),
    'tiles': _tiles, 'carpet': _carpet, 'laminate': _laminate, 'cardboard': _cardboard,
    'books': _books, 'bricks': _bricks, 'concrete': _concrete, 'grass': _grass,
    'asphalt': _asphalt, 'pavers': _pavers, 'paper': _paper, 'paint': _paint,
    'window': _window, 'foliage': _foliage,
}
TEXTURE_IDS = {name: i for i, name in enumerate(TEXTURES)}
