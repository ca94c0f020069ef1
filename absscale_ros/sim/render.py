"""
CPU ray casting of a ``Scene`` with Open3D's RaycastingScene, then texturing and shading.

Speed (>= 10 frames/s at 1280x720 on two cores) comes from the scene being made of planar
faces: rays are cast on a 4-px grid first, and inside a 4x4 block whose four corner rays hit the
same face every ray hits that face's plane, so its hit is computed exactly by a ray-plane
intersection; all other blocks are cast ray by ray. A face smaller than the grid that touches
no grid ray is missed, identically in every render and in ``points_behind_pixels``. Pixels on a
face boundary get four more rays (rotated-grid supersampling), so sheet corners and cube edges
are anti-aliased and sub-pixel accurate.
"""
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt
import open3d as o3d

from absscale_ros.core.types import CameraModel
from absscale_ros.sim import camera as simcam
from absscale_ros.sim import rays, textures
from absscale_ros.sim.scene import Scene, SKY

F32 = npt.NDArray[np.float32]
FloatArray = npt.NDArray[np.float64]
BLOCK = 4  # px between grid rays of the first pass
CHUNK_ROWS = 48  # image rows shaded at once: arrays of ~60k pixels stay in the CPU cache
# Rotated-grid 4x supersampling offsets (px): no two samples share a row or a column.
SUBSAMPLES = ((-0.125, -0.375), (0.375, -0.125), (0.125, 0.375), (-0.375, 0.125))


@dataclass
class Frame:
    """
    One rendered view, before camera effects.

    :param colour: (H, W, 3) float32 display-encoded (gamma 2) RGB, 8-bit scale (0-255+).
    :param surface: (H, W) int32 surface id behind each pixel centre, ``SKY`` for none.
    :param depth_m: (H, W) float32 z of the hit in the camera frame, m; inf for sky.
    :param grid_points_world_m: (Hg, Wg, 3) hits of the 4-px grid rays (far away for sky).
    """

    colour: F32
    surface: npt.NDArray[np.int32]
    depth_m: F32
    grid_points_world_m: F32


class Renderer:
    """Renders one scene through one camera model; build once, call ``render`` per pose."""

    def __init__(self, scene: Scene, camera: CameraModel) -> None:
        self.scene = scene
        self.camera = camera
        self._rc = o3d.t.geometry.RaycastingScene()
        self._rc.add_triangles(o3d.core.Tensor(scene.vertices_m),
                               o3d.core.Tensor(scene.triangles))
        w, h = camera.width, camera.height
        self._pix = rays.Rays(camera, simcam.pixel_grid(w, h))
        self._grid_shape = (h // BLOCK + 1, w // BLOCK + 1)
        self._grid = rays.Rays(camera, simcam.pixel_grid(w, h, BLOCK))
        self._subs = [rays.Rays(camera, simcam.pixel_grid(w, h, 1, off)) for off in SUBSAMPLES]
        mats = scene.materials
        mat = scene.surface_material
        n = len(mat) + 1
        # Per-surface tables are indexed by "row" = surface id + 1 (row 0 is the sky), as uint8
        # so cv2.LUT can gather them.
        if n > 256:
            raise ValueError(f'{n - 1} surfaces: the renderer handles at most 255')
        self._tex_id = _lut([0] + [textures.TEXTURE_IDS[mats[m].texture] for m in mat])
        self._texel_m = np.concatenate([[1.0], [mats[m].texel_m for m in mat]])
        # lod = log2(pixel footprint / texel); footprint = Z |phi|^1.5 / (f sqrt|n.phi|).
        self._lod_offset = _lut(np.log2(1.0 / (camera.K[0, 0] * self._texel_m)))
        cos = np.clip(scene.normals @ scene.light_dir_world, 0.0, None)
        irradiance = scene.ambient + scene.direct * cos
        tint = np.array([mats[m].tint for m in mat])
        # Display-encoded (gamma 2) colour factor: sqrt of the linear irradiance.
        factor = np.vstack([[0.0, 0.0, 0.0], tint * np.sqrt(irradiance)[:, None]])
        self._factor = [_lut(factor[:, c]) for c in range(3)]

    def cast(self, T_world_cam: FloatArray, dirs_cam: F32) -> tuple[F32, npt.NDArray[np.int32]]:
        """
        Cast rays from the camera centre.

        :param dirs_cam: (N, 3) unit directions in the camera frame.
        :returns: (N,) distance along the ray, m (inf for sky); (N,) surface ids.
        """
        R = T_world_cam[:3, :3].astype(np.float32)
        origin_dir = np.empty((len(dirs_cam), 6), np.float32)
        origin_dir[:, :3] = T_world_cam[:3, 3].astype(np.float32)
        origin_dir[:, 3:] = rays.rotate(dirs_cam, R)
        hit = self._rc.cast_rays(o3d.core.Tensor(origin_dir))
        t = hit['t_hit'].numpy()
        prim = hit['primitive_ids'].numpy()
        missed = ~np.isfinite(t)
        surface = self.scene.tri_surface[np.where(missed, 0, prim)]
        surface[missed] = SKY
        return t, surface.astype(np.int32)

    def _tables(self, T_world_cam: FloatArray) -> F32:
        """
        Per-surface rows for this pose, camera frame: plane and texture mapping.

        :returns: (12, S + 1) columns n0 n1 n2 rhs | au0 au1 au2 cu | av0 av1 av2 cv, where
            the plane is ``n . p_cam = rhs`` and texture ``tx = Z (au . phi) + cu`` (texels)
            for the hit ``p_cam = Z phi``, ``phi = (x, y, 1)``.
        """
        sc = self.scene
        R, origin = T_world_cam[:3, :3], T_world_cam[:3, 3]
        out = np.zeros((12, 256))
        n = len(sc.normals) + 1
        out[0:3, 1:n] = (sc.normals @ R).T
        out[2, 0] = 1.0
        out[3, 1:n] = sc.offsets_m - sc.normals @ origin
        axes = sc.tex_axes / self._texel_m[1:, None, None]  # (S, 2, 3) texels per metre
        for k in range(2):
            out[4 + 4 * k:7 + 4 * k, 1:n] = (axes[:, k] @ R).T
            out[7 + 4 * k, 1:n] = axes[:, k] @ origin + sc.tex_origin_m[:, k] / self._texel_m[1:]
        return out.astype(np.float32)

    def depth(self, T_world_cam: FloatArray) -> tuple[F32, npt.NDArray[np.int32]]:
        """
        Z-depth and surface id of every pixel, exactly as ``render`` sees them.

        :returns: (H, W) float32 camera-frame z, m (inf for sky); (H, W) int32 surface ids.
        """
        h, w = self.camera.height, self.camera.width
        tab = self._tables(T_world_cam)
        row, _, _ = self._rows(T_world_cam)
        z = np.empty(h * w, np.float32)
        for s in self._chunks():
            z[s] = self._plane_z(tab, row[s], self._pix.x[s], self._pix.y[s])
        return z.reshape(h, w), row.reshape(h, w).astype(np.int32) - 1

    def _chunks(self) -> list[slice]:
        """Pixel ranges of CHUNK_ROWS image rows: per-pixel math then runs in the cache."""
        h, w = self.camera.height, self.camera.width
        return [slice(r * w, min(r + CHUNK_ROWS, h) * w) for r in range(0, h, CHUNK_ROWS)]

    def render(self, T_world_cam: FloatArray) -> Frame:
        """Render the view from ``T_world_cam`` (4x4, camera to world, m)."""
        h, w = self.camera.height, self.camera.width
        tab = self._tables(T_world_cam)
        row, grid_t, grid_s = self._rows(T_world_cam)
        grid_z = (grid_t * self._grid.dz).astype(np.float32)
        block_lod = self._block_lod(grid_z, grid_s, tab)
        pix = self._pix
        z = np.empty(h * w, np.float32)
        lod = np.empty(h * w, np.float32)
        colour = np.empty((h * w, 3), np.float32)
        for s in self._chunks():
            r = row[s]
            z[s] = self._plane_z(tab, r, pix.x[s], pix.y[s])
            lod[s] = block_lod[s] + textures.lookup(self._lod_offset, r)
            z0 = np.where(r == 0, np.float32(0.0), z[s])
            colour[s] = self._shade(T_world_cam, tab, r, z0, pix.x[s], pix.y[s], None, lod[s],
                                    (-1, w))
        if self.scene.outdoor:
            self._fill_sky(colour, row, T_world_cam)
        surface = row.reshape(h, w)
        # Pixels with a 4-neighbour on another surface get 4 more rays (anti-aliasing).
        edge = cv2.dilate(surface, _CROSS) != cv2.erode(surface, _CROSS)
        idx = np.flatnonzero(edge)
        if idx.size:
            self._antialias(T_world_cam, tab, idx, lod[idx], colour)
        return Frame(colour.reshape(h, w, 3), surface.astype(np.int32) - 1, z.reshape(h, w),
                     self._grid_points(T_world_cam, grid_z))

    def _antialias(self, T_world_cam: FloatArray, tab: F32, idx: npt.NDArray[np.intp],
                   lod: F32, colour: F32) -> None:
        """Replace the colour of pixels ``idx`` by the mean of their four sub-pixel rays."""
        dirs = np.concatenate([sub.dirs[idx] for sub in self._subs])
        t, srf = self.cast(T_world_cam, dirs)
        sub_row = (srf + 1).astype(np.uint8)
        dz = np.concatenate([sub.dz[idx] for sub in self._subs])
        sub_z = np.where(sub_row == 0, np.float32(0.0), t * dz)
        x = np.concatenate([sub.x[idx] for sub in self._subs])
        y = np.concatenate([sub.y[idx] for sub in self._subs])
        samples = self._shade(T_world_cam, tab, sub_row, sub_z, x, y, dirs,
                              np.tile(lod, len(self._subs)), None)
        colour[idx] = samples.reshape(len(self._subs), idx.size, 3).mean(axis=0)

    def _rows(self, T_world_cam: FloatArray) -> tuple[npt.NDArray[np.uint8], F32,
                                                      npt.NDArray[np.int32]]:
        """
        Surface row (id + 1, uint8; 0 = sky) of every pixel, and the grid rays' hits.

        The 4-px grid rays are cast first; a block whose four corners hit one face takes that
        face, the pixels of the other blocks are cast one by one.
        """
        h, w = self.camera.height, self.camera.width
        gh, gw = self._grid_shape
        gt, gs = self.cast(T_world_cam, self._grid.dirs)
        g = gs.reshape(gh, gw)
        uniform = (g[:-1, :-1] == g[1:, :-1]) & (g[:-1, :-1] == g[:-1, 1:]) \
            & (g[:-1, :-1] == g[1:, 1:])
        block = np.where(uniform, g[:-1, :-1] + 1, 0).astype(np.uint8)
        shape = (h // BLOCK, BLOCK, w // BLOCK, BLOCK)
        row = np.ascontiguousarray(np.broadcast_to(block[:, None, :, None], shape)).reshape(-1)
        mixed = np.flatnonzero(np.broadcast_to(~uniform[:, None, :, None], shape))
        if mixed.size:
            _, srf = self.cast(T_world_cam, self._pix.dirs[mixed])
            row[mixed] = (srf + 1).astype(np.uint8)
        return row, gt, gs

    @staticmethod
    def _plane_z(tab: F32, row: npt.NDArray[np.uint8], x: F32, y: F32) -> F32:
        """Z-depth of the hit on each pixel's face plane (exact ray-plane intersection)."""
        lk = textures.lookup
        nd = lk(tab[0], row) * x + lk(tab[1], row) * y + lk(tab[2], row)
        with np.errstate(divide='ignore', invalid='ignore'):
            z = lk(tab[3], row) / nd
        z[row == 0] = np.inf
        return z

    def _block_lod(self, grid_z: F32, grid_surface: npt.NDArray[np.int32], tab: F32) -> F32:
        """
        Per pixel, the geometric part of the mip level: log2 of the footprint in metres.

        The mip level only sets how blurred a texture is, so it is evaluated at the grid rays
        and held over each 4x4 block (the sharpest of the block's corners).
        """
        h, w = self.camera.height, self.camera.width
        gh, gw = self._grid_shape
        r = (grid_surface + 1).astype(np.uint8)
        gr = self._grid
        nd = textures.lookup(tab[0], r) * gr.x + textures.lookup(tab[1], r) * gr.y \
            + textures.lookup(tab[2], r)
        with np.errstate(divide='ignore', invalid='ignore'):
            q = grid_z * grid_z * gr.norm_cubed / np.abs(nd)
        q = np.where(np.isfinite(q) & (q > 0), q, np.float32(1e6)).reshape(gh, gw)
        q = np.minimum(np.minimum(q[:-1, :-1], q[1:, :-1]), np.minimum(q[:-1, 1:], q[1:, 1:]))
        lod = (0.5 * np.log2(q)).astype(np.float32)
        return np.ascontiguousarray(np.broadcast_to(
            lod[:, None, :, None], (h // BLOCK, BLOCK, w // BLOCK, BLOCK))).reshape(-1)

    def _grid_points(self, T_world_cam: FloatArray, grid_z: F32) -> F32:
        gh, gw = self._grid_shape
        far = np.where(np.isfinite(grid_z), grid_z, np.float32(1e5))
        pts_cam = np.stack([self._grid.x * far, self._grid.y * far, far], axis=1)
        pts = rays.rotate(pts_cam, T_world_cam[:3, :3]) + T_world_cam[:3, 3]
        return pts.astype(np.float32).reshape(gh, gw, 3)

    def _shade(self, T_world_cam: FloatArray, tab: F32, row: npt.NDArray[np.uint8], z: F32,
               x: F32, y: F32, dirs: F32 | None, lod: F32,
               shape: tuple[int, int] | None) -> F32:
        """
        Display-encoded colour: texture x tint x sqrt(Lambert irradiance); sky where row 0.

        :param row: (N,) surface id + 1; :param z: (N,) z-depth, 0 for sky;
        :param x: (N,) undistorted normalised ray coordinates, ``y`` likewise;
        :param dirs: (N, 3) unit rays to shade the sky with, or None when the caller fills it;
        :param lod: (N,) mip lod; :param shape: image-like shape of the N rays, or None.
        :returns: (N, 3) float32 RGB, 8-bit scale.
        """
        lk = textures.lookup
        tx = z * (lk(tab[4], row) * x + lk(tab[5], row) * y + lk(tab[6], row))
        tx += lk(tab[7], row)
        ty = z * (lk(tab[8], row) * x + lk(tab[9], row) * y + lk(tab[10], row))
        ty += lk(tab[11], row)
        colour = textures.sample(lk(self._tex_id, row).astype(np.uint8), tx, ty, lod, shape)
        factor = cv2.merge([lk(f, row).reshape(-1, 1) for f in self._factor])
        colour *= factor.reshape(-1, 3)
        if dirs is not None and self.scene.outdoor:
            sky = np.flatnonzero(row == 0)
            if sky.size:
                colour[sky] = self._sky(rays.dot(dirs[sky], T_world_cam[2, :3]))
        return colour

    def _fill_sky(self, colour: F32, row: npt.NDArray[np.uint8], T_world_cam: FloatArray) -> None:
        """Sky of a whole image: the gradient is smooth, so evaluate it on the grid and resize."""
        sky = row == 0
        if not sky.any():
            return
        h, w = self.camera.height, self.camera.width
        up = rays.dot(self._grid.dirs, T_world_cam[2, :3])
        grid = self._sky(up).reshape(*self._grid_shape, 3)[:-1, :-1]
        full = cv2.resize(grid, (w, h), interpolation=cv2.INTER_LINEAR)
        # The shader left the sky black (row 0 has a zero colour factor): add it there.
        cv2.add(colour.reshape(h, w, 3), full, dst=colour.reshape(h, w, 3),
                mask=sky.reshape(h, w).view(np.uint8))

    def _sky(self, up: F32) -> F32:
        """Hazy blue gradient with the ray's world z (indoor scenes are closed: no sky)."""
        up = np.sqrt(np.clip(up, 0.0, 1.0))[:, None]
        horizon = np.array([0.85, 0.88, 0.92], np.float32)
        zenith = np.array([0.45, 0.62, 0.88], np.float32)
        return (255.0 * (horizon + (zenith - horizon) * up)).astype(np.float32)


def _lut(values: object) -> F32:
    """A (256,) float32 cv2.LUT table holding ``values`` first."""
    out = np.zeros(256, np.float32)
    v = np.asarray(values, np.float32).ravel()
    out[:len(v)] = v
    return out


_CROSS = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
