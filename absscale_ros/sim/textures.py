"""
Procedural, tileable textures packed into one mip-mapped atlas for fast lookup.

Values are display-encoded (gamma 2): the renderer's shading, exposure and vignetting are
products, and a product commutes with a power law, so the shader multiplies encoded texels by
``sqrt`` of the linear factors and never converts per pixel. Textures do not depend on the
scene seed (the atlas is built once per process); surfaces get random texture origins instead.
"""
from dataclasses import dataclass
import functools

import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.sim import patterns
from absscale_ros.sim.patterns import TILE

LEVELS = 8  # 1024 .. 8 texels
PAD = 2  # wrapped border texels around each tile so bilinear lookups never cross tiles
COLUMNS = 5
LOD_BIAS = 1.0  # 0.5 rounds to the nearest level; 1.0 takes the coarser one
TEXTURE_SEED = 20240611
F32 = npt.NDArray[np.float32]
TEXTURES = patterns.TEXTURES
TEXTURE_IDS = patterns.TEXTURE_IDS


@dataclass(frozen=True)
class Atlas:
    """
    All textures at all mip levels in one image, with wrapped borders.

    :param image: (H, W, 3) uint8 display-encoded texels.
    :param origins: (n_textures, LEVELS, 2) float32 atlas position (x, y) of texel (0, 0).
    """

    image: npt.NDArray[np.uint8]
    origins: F32


@functools.lru_cache(maxsize=1)
def atlas() -> Atlas:
    """Build (once per process) the atlas of every texture in ``TEXTURES``."""
    rng = np.random.default_rng(TEXTURE_SEED)
    rows = (len(TEXTURES) + COLUMNS - 1) // COLUMNS
    heights = [rows * ((TILE >> lv) + 2 * PAD) for lv in range(LEVELS)]
    image = np.zeros((sum(heights), COLUMNS * (TILE + 2 * PAD), 3), np.uint8)
    origins = np.zeros((len(TEXTURES), LEVELS, 2), np.float32)
    for k, make in enumerate(TEXTURES.values()):
        level = np.clip(make(rng), 0.0, 1.0).astype(np.float32)
        y0 = 0
        for lv in range(LEVELS):
            size = TILE >> lv
            slot = size + 2 * PAD
            x, y = (k % COLUMNS) * slot, y0 + (k // COLUMNS) * slot
            image[y:y + slot, x:x + slot] = np.round(
                255.0 * np.pad(level, ((PAD, PAD), (PAD, PAD), (0, 0)), mode='wrap'))
            origins[k, lv] = (x + PAD, y + PAD)
            # pyrDown on a wrapped copy keeps the next level tileable.
            wrapped = np.pad(level, ((4, 4), (4, 4), (0, 0)), mode='wrap')
            level = cv2.pyrDown(wrapped)[2:2 + size // 2, 2:2 + size // 2]
            y0 += heights[lv]
    return Atlas(image, origins)


def lookup(table: F32, index8: npt.NDArray[np.uint8]) -> F32:
    """``table[index8]`` for a (256,) float32 table: cv2.LUT is ~5x faster than np.take."""
    return cv2.LUT(index8.reshape(-1, 1), table).reshape(-1)


def sample(tex_ids: npt.NDArray[np.uint8], tx: F32, ty: F32, lod: F32,
           shape: tuple[int, int] | None = None) -> F32:
    """
    Bilinear lookup at the mip level nearest to ``lod``.

    :param tex_ids: (N,) uint8 texture index per sample.
    :param tx: (N,) texture coordinate in level-0 texels (any real value: textures repeat).
    :param ty: (N,) same for the other axis.
    :param lod: (N,) log2 of the pixel footprint in level-0 texels.
    :param shape: (rows, cols) with rows * cols = N to remap as an image (faster), or None.
    :returns: (N, 3) float32 display-encoded colour in [0, 255].
    """
    at = atlas()
    tables = _slot_tables()
    # Level ceil(lod): a texel never smaller than a pixel, like a real lens + demosaicing.
    level = np.clip(lod + np.float32(LOD_BIAS), 0, LEVELS - 1).astype(np.uint8)
    slot = tex_ids * np.uint8(LEVELS) + level  # < 256 while there are <= 32 textures
    scale = lookup(tables[0], slot)
    size = lookup(tables[1], slot)
    maps = []
    for coord, origin in ((tx, tables[2]), (ty, tables[3])):
        m = coord * scale
        m -= np.floor(m / size) * size  # wrap into the tile
        m += lookup(origin, slot)
        maps.append(m)
    if shape is not None:
        out = cv2.remap(at.image, maps[0].reshape(shape), maps[1].reshape(shape),
                        cv2.INTER_LINEAR).reshape(-1, 3)  # shape may hold one -1
    else:
        out = remap_flat(at.image, maps[0], maps[1])
    return out.astype(np.float32)


@functools.lru_cache(maxsize=1)
def _slot_tables() -> F32:
    """(4, 256) per slot (texture * LEVELS + level): scale, tile size, atlas origin x, y."""
    at = atlas()
    out = np.ones((4, 256), np.float32)
    n = len(TEXTURES) * LEVELS
    levels = np.tile(np.arange(LEVELS), len(TEXTURES))
    out[0, :n] = np.ldexp(1.0, -levels)
    out[1, :n] = TILE * out[0, :n]
    out[2, :n] = at.origins[:, :, 0].ravel()
    out[3, :n] = at.origins[:, :, 1].ravel()
    return out


def remap_flat(image: npt.NDArray[np.uint8], mx: F32, my: F32,
               border: int = cv2.BORDER_REPLICATE) -> npt.NDArray[np.uint8]:
    """cv2.remap for flat coordinate lists (remap wants both map sides below 32767)."""
    n = len(mx)
    cols = 1024
    rows = (n + cols - 1) // cols
    pad = rows * cols - n
    maps = [np.pad(m.astype(np.float32), (0, pad)).reshape(rows, cols) for m in (mx, my)]
    out = cv2.remap(image, maps[0], maps[1], cv2.INTER_LINEAR, borderMode=border)
    return out.reshape(rows * cols, -1)[:n]
