"""
Calibration-object models: sizes, vertex ids, edges and known lengths.

Two kinds of target, as in the paper: a flat sheet of paper (letter, A4 or any rectangle) for
indoor scenes and a cube with three face colours (opposite faces alike, 0.8 m) for outdoor
scenes. Detection (``detect_sheet``, ``detect_cube``) reports 2D vertices with the ids defined
here; the scale stage reuses the edges and their lengths.

Vertex ids in one image
-----------------------
Sheet: 0..3, the four corners in clockwise order on screen (image y down) starting from the
corner nearest the image's top-left (smallest ``u + v``). A blank sheet has no printed
orientation, so this is the only order that every view can reproduce (matching across views
then needs only a cyclic shift, the paper's "same clockwise order").

Cube: every cube vertex touches one face of each colour, so colour alone cannot tell the 8
vertices apart (the paper's Step 2 matching does that). In one image a vertex is named by the
colours that meet there: ``vertex_id & 7`` is a bit mask (1 red, 2 yellow, 4 purple) and
``vertex_id >> 3`` counts vertices with the same mask in clockwise order from the top, so
ids stay unique when the same colours meet at two image vertices (two faces seen edge-on).
"""
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

# Sheet sizes in metres, (short side, long side).
SHEET_SIZES_M: dict[str, tuple[float, float]] = {
    'letter': (0.2159, 0.2794),
    'a4': (0.210, 0.297),
}

CUBE_EDGE_M = 0.8  # the paper's outdoor cube
# Face colour names in bit order of the cube vertex id.
CUBE_COLOURS: tuple[str, ...] = ('red', 'yellow', 'purple')
COLOUR_BITS: dict[str, int] = {name: 1 << i for i, name in enumerate(CUBE_COLOURS)}
TARGET_TYPES: tuple[str, ...] = ('sheet', 'cube')
# Integer codes of target types, used in the vertices point cloud (field ``target_type``).
TARGET_TYPE_CODES: dict[str, int] = {'sheet': 0, 'cube': 1}


@dataclass(frozen=True)
class SheetModel:
    """
    A flat rectangle of known size.

    :param width_m: short side, m.
    :param height_m: long side, m.
    :param name: 'letter', 'a4' or 'custom'.
    """

    width_m: float
    height_m: float
    name: str = 'custom'

    def __post_init__(self) -> None:
        if not 0.0 < self.width_m <= self.height_m:
            raise ValueError(f'sheet sides must satisfy 0 < width <= height, got '
                             f'{self.width_m} x {self.height_m} m')

    @property
    def aspect(self) -> float:
        """Long side over short side (>= 1)."""
        return self.height_m / self.width_m

    def edges(self) -> npt.NDArray[np.int64]:
        """(4, 2) vertex-id pairs of the sheet's sides, clockwise."""
        return np.array([[0, 1], [1, 2], [2, 3], [3, 0]], dtype=np.int64)


def sheet_model(name: str, size_m: tuple[float, float] | None = None) -> SheetModel:
    """
    Return the model of a named sheet ('letter', 'a4') or of a custom ``size_m``.

    :raises ValueError: on an unknown name without a size.
    """
    if size_m is not None:
        short, long_ = sorted(float(x) for x in size_m)
        return SheetModel(short, long_, name)
    if name not in SHEET_SIZES_M:
        raise ValueError(f'unknown sheet {name!r}; known: {sorted(SHEET_SIZES_M)} or a size')
    return SheetModel(*SHEET_SIZES_M[name], name)


@dataclass(frozen=True)
class CubeModel:
    """
    A cube whose opposite faces share a colour.

    Model vertex ``i`` (0..7) sits at ``edge_m * (i & 1, i >> 1 & 1, i >> 2 & 1)``; red faces are
    x = const, yellow y = const, purple z = const.

    :param edge_m: edge length, m.
    """

    edge_m: float = CUBE_EDGE_M

    def __post_init__(self) -> None:
        if self.edge_m <= 0.0:
            raise ValueError(f'cube edge must be positive, got {self.edge_m} m')

    def vertices_m(self) -> npt.NDArray[np.float64]:
        """(8, 3) vertex positions in the cube frame, m."""
        idx = np.arange(8)
        bits = np.stack([idx & 1, (idx >> 1) & 1, (idx >> 2) & 1], axis=1)
        return self.edge_m * bits.astype(np.float64)

    def edges(self) -> npt.NDArray[np.int64]:
        """(12, 2) model-vertex pairs joined by an edge (differ in exactly one bit)."""
        pairs = [(i, i | b) for i in range(8) for b in (1, 2, 4) if not i & b]
        return np.array(pairs, dtype=np.int64)


def colour_mask(vertex_id: int) -> int:
    """Return the colour bit mask of a cube image vertex id (see the module docstring)."""
    return int(vertex_id) & 7


def cube_vertex_id(mask: int, ordinal: int) -> int:
    """Return the image vertex id for colour ``mask`` and same-mask ``ordinal``."""
    return (int(ordinal) << 3) | (int(mask) & 7)


HELD_SCORE = -1.0  # a vertex held from an earlier frame (TargetDetection.vertex_scores)


@dataclass(frozen=True, eq=False)
class TargetDetection:
    """
    One calibration object found in one image.

    :param target_type: 'sheet' or 'cube'.
    :param name: model name ('letter', 'a4', 'custom' or 'cube').
    :param vertices_px: (N, 2) float64 image vertices (u, v), px, full-resolution image.
    :param vertex_ids: (N,) int64 ids as defined in this module's docstring.
    :param edges: (E, 2) int64 pairs of indices into ``vertices_px`` joined by an image edge.
    :param polygons: region outlines by label ('sheet', or a face colour), each a (K, 2)
        float64 polygon in px; used to measure pixel precision and recall.
    :param score: edge support in [0, 1] (fraction of the outline backed by image gradient).
    :param object_id: index of the object in its frame (set by ``detect.detect``).
    :param vertex_scores: (N,) float64 per-vertex score in [0, 1], or None when every vertex
        has ``score``. A vertex not seen but extrapolated (a sheet corner hidden by an object
        or outside the image, ``sheet_partial``) scores at most 0.5: later stages can weigh or
        drop it. ``HELD_SCORE`` (negative): a vertex of a face held from an earlier frame's
        cube (``cube_hold``), not confirmed as a cube in this frame: reported, but the map
        leaves it out (``sfm_outputs.vertices_from_rows``).
    """

    target_type: str
    name: str
    vertices_px: npt.NDArray[np.float64]
    vertex_ids: npt.NDArray[np.int64]
    edges: npt.NDArray[np.int64]
    polygons: tuple[tuple[str, npt.NDArray[np.float64]], ...]
    score: float
    object_id: int = 0
    vertex_scores: npt.NDArray[np.float64] | None = None

    def scores(self) -> npt.NDArray[np.float64]:
        """Return the (N,) per-vertex scores (``score`` everywhere unless given)."""
        if self.vertex_scores is None:
            return np.full(len(self.vertices_px), self.score)
        return np.asarray(self.vertex_scores, dtype=np.float64)


def sheet_sizes_m(sheet: str, custom_m: tuple[float, float] | None = None
                  ) -> list[tuple[float, float]]:
    """
    The (short, long) sheet sizes to try, m, the configured one first.

    :param sheet: a name of ``SHEET_SIZES_M``, or 'auto' for all of them (the scale stage then
        keeps the one the reconstructed corners fit).
    :param custom_m: a custom size, which overrides ``sheet``.
    """
    names = list(SHEET_SIZES_M) if sheet == 'auto' and not custom_m else [sheet]
    return [(m.width_m, m.height_m) for m in (sheet_model(n, custom_m) for n in names)]
