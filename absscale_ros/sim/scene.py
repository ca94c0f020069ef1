"""
Scene description for the simulator: planar convex faces with materials, targets, light.

A scene is a list of planar convex polygons ("surfaces"), each triangulated for ray casting.
Every surface carries its plane, a material and a texture frame fixed in the world, so the
texture under a pixel is a function of the world point only (features stay on the surfaces,
as SfM needs). Targets (sheet, cube) are surfaces too, with their model kept beside them.
"""
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
SKY = -1  # surface id of a ray that hits nothing

# Cube face axes in the cube's own frame: face id -> (axis, sign); opposite faces alike.
CUBE_FACES = ((0, -1), (0, 1), (1, -1), (1, 1), (2, -1), (2, 1))
CUBE_AXIS_COLOURS = ('red', 'yellow', 'purple')  # +-x, +-y, +-z of the cube's own frame


@dataclass(frozen=True)
class Material:
    """A texture from ``textures.TEXTURES`` scaled to the world and tinted."""

    texture: str
    tint: tuple[float, float, float] = (1.0, 1.0, 1.0)  # linear RGB multiplier
    texel_m: float = 0.004  # world size of one level-0 texel


@dataclass(frozen=True)
class Target:
    """
    Calibration object model in world coordinates.

    :param vertices_world_m: (V, 3) vertices, m.
    :param faces: per face the vertex ids, counter-clockwise seen from outside.
    :param colours: per face colour name.
    """

    kind: str
    name: str
    size_m: tuple[float, ...]
    vertices_world_m: FloatArray
    edges: tuple[tuple[int, int], ...]
    faces: tuple[tuple[int, ...], ...]
    colours: tuple[str, ...]


@dataclass
class Scene:
    """Finished scene: arrays for the ray caster and the shader, plus ground-truth facts."""

    name: str
    seed: int
    variant: dict[str, object]
    vertices_m: npt.NDArray[np.float32]  # (V, 3) world
    triangles: npt.NDArray[np.uint32]  # (T, 3)
    tri_surface: npt.NDArray[np.int32]  # (T,) surface id of each triangle
    normals: FloatArray  # (S, 3) unit normal of each surface (towards the viewer side)
    offsets_m: FloatArray  # (S,) plane offset: normal . x = offset
    tex_axes: FloatArray  # (S, 2, 3) world directions of texture u and v
    tex_origin_m: FloatArray  # (S, 2) texture coordinate of the world origin, m
    surface_material: npt.NDArray[np.int32]  # (S,)
    surface_target: npt.NDArray[np.int32]  # (S,) target id or -1
    surface_face: npt.NDArray[np.int32]  # (S,) face id in its target or -1
    materials: list[Material]
    targets: list[Target]
    light_dir_world: FloatArray  # (3,) unit vector towards the light
    ambient: float
    direct: float
    outdoor: bool
    distractors: list[dict[str, object]] = field(default_factory=list)
    point_pairs: list[dict[str, object]] = field(default_factory=list)
    walk: dict[str, float] = field(default_factory=dict)  # hints for trajectory.py
    obstacles: list[FloatArray] = field(default_factory=list)  # (2, 3) AABBs the camera avoids


class SceneBuilder:
    """Collect faces, boxes and targets; ``build`` turns them into a ``Scene``."""

    def __init__(self, rng: np.random.Generator) -> None:
        self._rng = rng
        self._polys: list[FloatArray] = []
        self._normals: list[FloatArray] = []
        self._material: list[int] = []
        self._target: list[tuple[int, int]] = []
        self.materials: list[Material] = []
        self._material_ids: dict[Material, int] = {}
        self.targets: list[Target] = []
        self.distractors: list[dict[str, object]] = []
        self.point_pairs: list[dict[str, object]] = []
        self.walk: dict[str, float] = {}
        self.obstacles: list[FloatArray] = []

    def material(self, mat: Material) -> int:
        """Return the id of ``mat``, registering it on first use."""
        if mat not in self._material_ids:
            self._material_ids[mat] = len(self.materials)
            self.materials.append(mat)
        return self._material_ids[mat]

    def face(self, corners_m: FloatArray, mat: Material, target: tuple[int, int] = (-1, -1),
             toward_m: FloatArray | None = None) -> None:
        """
        Add one planar convex polygon.

        :param corners_m: (k, 3) corners in order around the polygon, m.
        :param toward_m: a point on the side the normal must face (default: the side the
            corners' counter-clockwise order gives).
        """
        corners = np.asarray(corners_m, dtype=np.float64)
        n = np.cross(corners[1] - corners[0], corners[2] - corners[0])
        n /= np.linalg.norm(n)
        if toward_m is not None and np.dot(np.asarray(toward_m) - corners[0], n) < 0:
            n = -n
        self._polys.append(corners)
        self._normals.append(n)
        self._material.append(self.material(mat))
        self._target.append(target)

    def box(self, centre_m: FloatArray, size_m: FloatArray, yaw_rad: float,
            mat: Material | list[Material], inward: bool = False, label: str = '',
            pairs: bool = True, skip: tuple[int, ...] = (4,)) -> FloatArray:
        """
        Add a box standing upright (6 faces); returns its (8, 3) corners.

        :param centre_m: centre of the box, m.
        :param size_m: (3,) extents along the box's own x, y, z, m.
        :param mat: one material, or six for -x +x -y +y -z +z.
        :param inward: normals face the inside (a room).
        :param pairs: record three box edges as scene point pairs with true distances.
        :param skip: faces never seen, left out (default: the bottom, standing on the floor);
            the renderer handles at most 255 faces.
        """
        mats = mat if isinstance(mat, list) else [mat] * 6
        corners = box_corners(np.asarray(centre_m, float), np.asarray(size_m, float), yaw_rad)
        for fid, (axis, sign) in enumerate(CUBE_FACES):
            if fid in skip:
                continue
            ids = face_vertex_ids(axis, sign)
            outward = corners[list(ids)].mean(axis=0) - np.asarray(centre_m, float)
            toward = np.asarray(centre_m, float) + (-outward if inward else 2.0 * outward)
            self.face(corners[list(ids)], mats[fid], toward_m=toward)
        if pairs and label:
            for a, b in ((0, 1), (0, 2), (0, 4)):
                self.pair(corners[a], corners[b], f'{label} edge {a}-{b}', 'scene')
        if not inward:
            self.obstacles.append(np.stack([corners.min(axis=0), corners.max(axis=0)]))
        return corners

    def decals(self, rng: np.random.Generator, count: int, centre_xy_m: FloatArray,
               radius_m: float, z_m: float, mats: list[Material],
               keep_out: list[tuple[FloatArray, float]]) -> None:
        """
        Flat patches lying on a floor at height ``z_m`` (stains, litter, markings, rugs).

        Textures repeat every few metres; these patches sit at random places with random
        content, so feature matching sees unique structure all over the floor.

        :param keep_out: (centre_xy, radius) discs left free (the target and its support).
        """
        for _ in range(count):
            for _ in range(20):
                r = radius_m * np.sqrt(rng.uniform(0.02, 1.0))
                az = rng.uniform(0.0, 2.0 * np.pi)
                xy = np.asarray(centre_xy_m, float) + r * np.array([np.cos(az), np.sin(az)])
                if all(np.linalg.norm(xy - c) > rad for c, rad in keep_out):
                    break
            w, h = rng.uniform(0.08, 0.7, size=2)
            yaw = rng.uniform(0.0, np.pi)
            c, s = np.cos(yaw), np.sin(yaw)
            local = np.array([[-w, -h], [w, -h], [w, h], [-w, h]]) * 0.5 @ np.array(
                [[c, s], [-s, c]])
            corners = np.column_stack([xy + local, np.full(4, z_m)])
            self.face(corners, mats[int(rng.integers(len(mats)))],
                      toward_m=[xy[0], xy[1], z_m + 1.0])

    def pair(self, a_m: FloatArray, b_m: FloatArray, label: str, kind: str) -> None:
        """Record two world points and their true distance."""
        a, b = np.asarray(a_m, float), np.asarray(b_m, float)
        self.point_pairs.append({'a_world_m': a.tolist(), 'b_world_m': b.tolist(),
                                 'distance_m': float(np.linalg.norm(a - b)),
                                 'label': label, 'kind': kind})

    def add_target(self, target: Target, mats: list[Material]) -> int:
        """Add a target's faces (one material per face) and its edge / diagonal pairs."""
        tid = len(self.targets)
        self.targets.append(target)
        v = target.vertices_world_m
        centre = v.mean(axis=0)
        for fid, ids in enumerate(target.faces):
            normal_side = None if target.kind == 'sheet' else 2.0 * v[list(ids)].mean(0) - centre
            self.face(v[list(ids)], mats[fid], target=(tid, fid), toward_m=normal_side)
        for a, b in target.edges:
            self.pair(v[a], v[b], f'{target.name} edge {a}-{b}', 'target_edge')
        if target.kind == 'sheet':
            self.pair(v[0], v[2], f'{target.name} diagonal 0-2', 'target_diagonal')
            self.pair(v[1], v[3], f'{target.name} diagonal 1-3', 'target_diagonal')
        else:
            self.pair(v[0], v[7], f'{target.name} diagonal 0-7', 'target_diagonal')
        return tid

    def build(self, name: str, seed: int, variant: dict[str, object], light_dir: FloatArray,
              ambient: float, direct: float, outdoor: bool) -> Scene:
        """Triangulate (fans: faces are convex) and pack the per-surface arrays."""
        verts, tris, tri_surface = [], [], []
        base = 0
        for sid, poly in enumerate(self._polys):
            verts.append(poly)
            for k in range(1, len(poly) - 1):
                tris.append((base, base + k, base + k + 1))
                tri_surface.append(sid)
            base += len(poly)
        normals = np.array(self._normals)
        offsets = np.array([np.dot(n, p[0]) for n, p in zip(normals, self._polys)])
        u_axes = np.array([_texture_u_axis(n) for n in normals])
        axes = np.stack([u_axes, np.cross(normals, u_axes)], axis=1)
        # A random texture origin per surface: neighbouring walls do not show the same pattern.
        tex_origin = self._rng.uniform(0.0, 40.0, size=(len(normals), 2))
        targets = np.array(self._target, dtype=np.int32).reshape(-1, 2)
        light = np.asarray(light_dir, float) / np.linalg.norm(light_dir)
        return Scene(name, seed, variant, np.concatenate(verts).astype(np.float32),
                     np.array(tris, dtype=np.uint32), np.array(tri_surface, dtype=np.int32),
                     normals, offsets, axes, tex_origin, np.array(self._material, np.int32),
                     targets[:, 0].copy(), targets[:, 1].copy(), self.materials, self.targets,
                     light, ambient, direct, outdoor, self.distractors, self.point_pairs,
                     self.walk, self.obstacles)


def _texture_u_axis(normal: FloatArray) -> FloatArray:
    """Texture u along the horizontal on walls (bricks stay level), along x on floors."""
    horizontal = np.cross([0.0, 0.0, 1.0], normal)
    if np.linalg.norm(horizontal) < 1e-6:
        return np.array([1.0, 0.0, 0.0])
    return horizontal / np.linalg.norm(horizontal)


def box_corners(centre_m: FloatArray, size_m: FloatArray, yaw_rad: float,
                rotation: FloatArray | None = None) -> FloatArray:
    """(8, 3) box corners; corner ``i`` has bit 0 = +x, bit 1 = +y, bit 2 = +z (own frame)."""
    bits = np.array([[(i >> k) & 1 for k in range(3)] for i in range(8)], dtype=float)
    local = (bits - 0.5) * size_m
    R = rotation if rotation is not None else rot_z(yaw_rad)
    return centre_m + local @ R.T


def face_vertex_ids(axis: int, sign: int) -> tuple[int, int, int, int]:
    """Corner ids of a box face, counter-clockwise seen from outside."""
    bit = 1 if sign > 0 else 0
    a, b = [k for k in range(3) if k != axis]
    # (a, b, axis) right-handed when axis follows a x b; flip the loop for the -axis face.
    loop = [(0, 0), (1, 0), (1, 1), (0, 1)]
    right_handed = (axis - a) % 3 == 2
    if (sign > 0) != right_handed:
        loop = loop[::-1]
    ids = tuple((bit << axis) | (i << a) | (j << b) for i, j in loop)
    return ids  # type: ignore[return-value]


def rot_z(angle_rad: float) -> FloatArray:
    """Rotation about world z."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
