"""``indoor_paper``: a 3-7 m room with furniture and a letter / A4 sheet on a darker surface."""
import numpy as np

from absscale_ros.sim import targets
from absscale_ros.sim.scene import Material, Scene, SceneBuilder

FLOORS = [Material('parquet', (1.0, 1.0, 1.0), 0.0015), Material('tiles', (1.0, 1.0, 1.0), 0.0015),
          Material('carpet', (1.0, 1.0, 1.0), 0.0008)]
WALLS = [Material('plaster', (0.95, 0.93, 0.88), 0.002),
         Material('wallpaper', (1.0, 1.0, 1.0), 0.0015),
         Material('plaster', (0.85, 0.9, 0.95), 0.002)]
CEILING = Material('ceiling', (1.0, 1.0, 1.0), 0.0025)
DESK_DARK = Material('wood_dark', (1.0, 1.0, 1.0), 0.001)
DESK_LIGHT = Material('laminate', (0.97, 0.97, 0.97), 0.0008)  # only slightly darker than paper
WOOD = Material('parquet', (0.9, 0.85, 0.8), 0.0012)
BOOKS = Material('books', (1.0, 1.0, 1.0), 0.0018)
CARDBOARD = Material('cardboard', (1.0, 1.0, 1.0), 0.0008)
MUG = Material('paint', (0.25, 0.45, 0.7), 0.0005)
FLOOR_DECALS = [Material('carpet', (0.9, 0.75, 0.6), 0.0008),
                Material('cardboard', (1.0, 1.0, 1.0), 0.0006),
                Material('wood_dark', (0.9, 0.9, 0.9), 0.001),
                Material('tiles', (0.6, 0.6, 0.65), 0.0004)]


def build(seed: int, variant: dict[str, object], rng: np.random.Generator) -> Scene:
    """
    Build the indoor scene of ``seed``.

    :param variant: ``target`` (letter / a4), ``support`` (desk / floor / light_desk),
        ``distractors``, ``occluded`` (see docs/gt_schema.md).
    """
    b = SceneBuilder(rng)
    lx, ly, lz = rng.uniform(3.5, 7.0), rng.uniform(4.5, 7.2), rng.uniform(2.5, 3.0)
    walls = [WALLS[rng.integers(len(WALLS))] for _ in range(4)]
    b.box([lx / 2, ly / 2, lz / 2], [lx, ly, lz], 0.0,
          walls + [FLOORS[rng.integers(len(FLOORS))], CEILING], inward=True, pairs=False, skip=())
    b.pair([0.0, 0.0, 0.0], [lx, 0.0, 0.0], 'room width at floor', 'scene')
    b.pair([0.0, 0.0, 0.0], [0.0, ly, 0.0], 'room depth at floor', 'scene')
    # Desk against the far wall (y = ly); the camera walks in from the near wall.
    dw, dd, dh = rng.uniform(1.2, 1.6), rng.uniform(0.65, 0.8), rng.uniform(0.72, 0.76)
    dx = rng.uniform(0.9 + dw / 2, max(0.9 + dw / 2, lx - 0.9 - dw / 2))
    dy = ly - dd / 2 - 0.05
    desk_mat = DESK_LIGHT if variant['support'] == 'light_desk' else DESK_DARK
    b.box([dx, dy, dh - 0.015], [dw, dd, 0.03], 0.0, desk_mat, label='desk top', skip=())
    for sx in (-1, 1):
        for sy in (-1, 1):
            b.box([dx + sx * (dw / 2 - 0.05), dy + sy * (dd / 2 - 0.05), (dh - 0.03) / 2],
                  [0.05, 0.05, dh - 0.03], 0.0, WOOD, pairs=False)
    kind = str(variant['target'])
    if variant['support'] == 'floor':
        centre = np.array([np.clip(dx + rng.uniform(-0.8, 0.8), 0.8, lx - 0.8),
                           dy - dd / 2 - rng.uniform(0.6, 1.2), 0.0003])
    else:
        centre = np.array([dx + rng.uniform(-0.3, 0.3) * (dw - 0.35),
                           dy + rng.uniform(-0.08, 0.02), dh + 0.0003])
    sheet = targets.sheet(kind, centre, rng.uniform(-0.5, 0.5) + rng.choice([0.0, np.pi / 2]))
    b.add_target(sheet, [targets.PAPER])
    _furniture(b, rng, lx, ly, lz, dx, dw)
    _wall_decor(b, rng, lx, ly, lz)
    if variant['distractors']:
        away = -1.0 if centre[0] > dx else 1.0  # keep the desk distractors off the sheet
        _distractors(b, rng, lx, ly, dx + away * 0.02, dy, dw, dd, dh, away)
    if variant['occluded']:
        # A mug over one corner: that corner and bits of two edges are hidden.
        corner = sheet.vertices_world_m[rng.integers(4)]
        toward = (centre - corner) / np.linalg.norm(centre - corner)
        pos = corner + 0.03 * toward + np.array([0.0, 0.0, 0.055])
        b.box(pos, [0.085, 0.085, 0.11], rng.uniform(0, np.pi), MUG, label='occluding mug')
    # Rugs, mats, dropped cardboard: unique structure on the floor (its pattern repeats).
    # Just above the floor, below a sheet or card lying on it (0.3 mm, 0.6 mm).
    b.decals(rng, 25, np.array([lx / 2, ly / 2]), 0.5 * min(lx, ly), 0.0002, FLOOR_DECALS,
             [(centre[:2], 0.7)])
    near = rng.uniform(0.75, 1.1)
    b.walk = {'target_x': centre[0], 'target_y': centre[1], 'target_z': centre[2],
              'approach_rad': -np.pi / 2 + rng.uniform(-0.3, 0.3),
              'orbit_rad': np.deg2rad(rng.uniform(35.0, 65.0)) * rng.choice([-1.0, 1.0]),
              'far_m': min(7.0, centre[1] - 0.45), 'mid_m': rng.uniform(1.8, 2.6), 'near_m': near,
              'eye_height_m': rng.uniform(1.4, 1.65), 'max_speed_mps': 1.4,
              'room_x0': 0.35, 'room_x1': lx - 0.35, 'room_y0': 0.35, 'room_y1': ly - 0.35}
    az, el = rng.uniform(0.0, 2.0 * np.pi), np.deg2rad(rng.uniform(50.0, 75.0))
    light = np.array([np.cos(az) * np.cos(el), np.sin(az) * np.cos(el), np.sin(el)])
    return b.build('indoor_paper', seed, variant, light, 0.45, 0.6, outdoor=False)


def _furniture(b: SceneBuilder, rng: np.random.Generator, lx: float, ly: float, lz: float,
               dx: float, dw: float) -> None:
    """Bookshelf beside the desk, cabinets and boxes along the side walls' far half."""
    free_left, free_right = dx - dw / 2 - 0.1, lx - (dx + dw / 2) - 0.1
    shelf_w = rng.uniform(0.8, 1.2)
    if max(free_left, free_right) > shelf_w:
        x = shelf_w / 2 + 0.05 if free_left > free_right else lx - shelf_w / 2 - 0.05
        h = rng.uniform(1.6, min(2.2, lz - 0.2))
        b.box([x, ly - 0.2, h / 2], [shelf_w, 0.35, h], 0.0,
              [WOOD, WOOD, BOOKS, WOOD, WOOD, WOOD], label='bookshelf')
    for k, wall_x in enumerate((0.3, lx - 0.3)):
        y = rng.uniform(ly * 0.55, ly - 1.2)
        h = rng.uniform(0.8, 1.3)
        b.box([wall_x, y, h / 2], [0.5, rng.uniform(0.8, 1.4), h], 0.0, WOOD, label=f'cabinet {k}')
        b.box([wall_x + (0.1 if k == 0 else -0.1), y + 0.1, h + 0.15], [0.35, 0.3, 0.3],
              rng.uniform(-0.3, 0.3), CARDBOARD, label=f'box on cabinet {k}')
    for k in range(int(rng.integers(2, 5))):
        s = rng.uniform(0.3, 0.6, size=3)
        x = rng.choice([rng.uniform(0.3, 0.9), rng.uniform(lx - 0.9, lx - 0.3)])
        b.box([x, rng.uniform(0.5, ly * 0.5), s[2] / 2], s, rng.uniform(0, np.pi), CARDBOARD,
              label=f'floor box {k}')


def _wall_decor(b: SceneBuilder, rng: np.random.Generator, lx: float, ly: float,
                lz: float) -> None:
    """Posters and a door: strong corners on otherwise weakly textured walls."""
    poster = Material('cardboard', (1.0, 1.0, 1.0), 0.0006)
    for k in range(int(rng.integers(3, 6))):
        w, h = rng.uniform(0.4, 0.9), rng.uniform(0.4, 0.8)
        z = rng.uniform(1.1, lz - 0.5)
        if k % 2 == 0:  # side walls
            x = 0.006 if k % 4 == 0 else lx - 0.006
            y = rng.uniform(0.6, ly - 0.6)
            pts = [[x, y - w / 2, z - h / 2], [x, y + w / 2, z - h / 2], [x, y + w / 2, z + h / 2],
                   [x, y - w / 2, z + h / 2]]
        else:  # near wall, seen when the camera turns around
            x = rng.uniform(0.6, lx - 0.6)
            pts = [[x - w / 2, 0.006, z - h / 2], [x + w / 2, 0.006, z - h / 2],
                   [x + w / 2, 0.006, z + h / 2], [x - w / 2, 0.006, z + h / 2]]
        b.face(np.array(pts), poster, toward_m=[lx / 2, ly / 2, z])
    y = rng.uniform(0.6, ly * 0.4)
    b.face(np.array([[0.006, y, 0.0], [0.006, y + 0.9, 0.0], [0.006, y + 0.9, 2.05],
                     [0.006, y, 2.05]]), WOOD, toward_m=[1.0, y, 1.0])


def _distractors(b: SceneBuilder, rng: np.random.Generator, lx: float, ly: float, dx: float,
                 dy: float, dw: float, dd: float, dh: float, side: float) -> None:
    """White rectangles that are not letter / A4, and brightly coloured things."""
    for size, where in (((0.148, 0.105), 'desk'), ((0.42, 0.297), 'floor'), ((1.2, 0.9), 'wall')):
        if where == 'desk':
            c = np.array([dx + side * (dw / 2 - 0.15), dy + rng.uniform(-0.1, 0.1), dh + 0.0006])
            corners = targets.rectangle(c, rng.uniform(0, np.pi), *size)
        elif where == 'floor':
            c = np.array([rng.uniform(0.8, lx - 0.8), rng.uniform(1.0, ly * 0.5), 0.0006])
            corners = targets.rectangle(c, rng.uniform(0, np.pi), *size)
        else:  # whiteboard on the far wall above the desk
            c = np.array([dx, ly - 0.006, 1.55])
            w, h = size
            corners = c + np.array([[-w, 0, -h], [w, 0, -h], [w, 0, h], [-w, 0, h]]) * 0.5
        b.face(corners, targets.PAPER, toward_m=c + [0.0, -1.0, 1.0])
        b.distractors.append({'kind': 'white_rectangle', 'colour': 'white', 'size_m': list(size),
                              'centre_world_m': c.tolist()})
    for colour, size in (('red', [0.3, 0.22, 0.12]), ('yellow', [0.24, 0.32, 0.03])):
        c = np.array([dx + side * rng.uniform(0.1, dw / 2 - 0.2), dy + 0.2, dh + size[2] / 2])
        b.box(c, size, rng.uniform(0, np.pi), targets.paint(colour), label=f'{colour} distractor')
        b.distractors.append({'kind': 'box', 'colour': colour, 'size_m': size,
                              'centre_world_m': c.tolist()})
