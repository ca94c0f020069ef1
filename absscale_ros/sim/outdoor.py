"""``outdoor_cube``: plaza with the 0.8 m cube, objects at 5-25 m, building facades beyond."""
import numpy as np

from absscale_ros.sim import targets
from absscale_ros.sim.scene import FloatArray, Material, rot_z, Scene, SceneBuilder

GRASS = Material('grass', (1.0, 1.0, 1.0), 0.004)
FACADES = [Material('bricks', (1.0, 1.0, 1.0), 0.0033),
           Material('concrete', (1.0, 1.0, 1.0), 0.004),
           Material('pavers', (1.0, 0.95, 0.9), 0.005),
           Material('plaster', (0.95, 0.85, 0.7), 0.01)]
GROUNDS = [Material('pavers', (1.0, 1.0, 1.0), 0.0025),
           Material('asphalt', (1.0, 1.0, 1.0), 0.002),
           Material('concrete', (0.95, 0.95, 0.95), 0.003)]
WINDOW = Material('window', (1.0, 1.0, 1.0), 0.004)
# Oil stains, repaired patches, litter, faded markings: unique features on a repetitive plaza.
DECALS = [Material('asphalt', (0.7, 0.7, 0.7), 0.0015),
          Material('concrete', (0.8, 0.78, 0.75), 0.001),
          Material('cardboard', (0.9, 0.85, 0.8), 0.0008),
          Material('paint', (0.55, 0.55, 0.52), 0.002),
          Material('grass', (0.8, 0.8, 0.8), 0.002)]
NEUTRAL_PAINTS = [(0.3, 0.4, 0.65), (0.55, 0.55, 0.57), (0.3, 0.3, 0.32), (0.85, 0.86, 0.88),
                  (0.25, 0.5, 0.4)]


def build(seed: int, variant: dict[str, object], rng: np.random.Generator) -> Scene:
    """
    Build the outdoor scene of ``seed``.

    :param variant: ``top_colour``, ``distractors``, ``occluded`` (see docs/gt_schema.md).
    """
    b = SceneBuilder(rng)
    yaw = rng.uniform(0.0, 2.0 * np.pi)
    cube = targets.cube(np.zeros(2), 0.0, yaw, str(variant['top_colour']))
    faces_mats = [targets.paint(c) for c in cube.colours]
    b.add_target(cube, faces_mats)
    approach = rng.uniform(0.0, 2.0 * np.pi)
    orbit = np.deg2rad(rng.uniform(50.0, 110.0)) * rng.choice([-1.0, 1.0])
    b.walk = {'target_x': 0.0, 'target_y': 0.0, 'target_z': 0.4, 'approach_rad': approach,
              'orbit_rad': orbit, 'far_m': rng.uniform(20.0, 25.0),
              'mid_m': rng.uniform(8.0, 11.0),
              'near_m': rng.uniform(3.0, 4.5), 'eye_height_m': rng.uniform(1.45, 1.7),
              'max_speed_mps': 3.0, 'room_x0': -1e3, 'room_x1': 1e3, 'room_y0': -1e3,
              'room_y1': 1e3}
    lo, hi = sorted([approach, approach + orbit])
    sector = (lo - np.deg2rad(35.0), hi + np.deg2rad(35.0))

    # Ground: a plaza at z = 0 (where the cube stands) inside a lawn 3 cm lower.
    half = rng.uniform(18.0, 26.0)
    square = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]])
    b.face(square * [half, half, 1.0], GROUNDS[rng.integers(len(GROUNDS))],
           toward_m=[0.0, 0.0, 10.0])
    b.face(square * [300.0, 300.0, 1.0] - [0.0, 0.0, 0.03], GRASS, toward_m=[0.0, 0.0, 10.0])
    _buildings(b, rng)
    placed: list[tuple[FloatArray, float]] = [(np.zeros(2), 1.5)]
    for k in range(int(rng.integers(12, 18))):
        _random_object(b, rng, placed, sector, k)
    if variant['distractors']:
        _distractors(b, rng, placed, approach)
    if variant['occluded']:
        az = approach + 0.5 * orbit + rng.uniform(-0.2, 0.2)
        pos = 1.25 * np.array([np.cos(az), np.sin(az)])
        b.box([pos[0], pos[1], 0.8], [0.3, 0.3, 1.6], az,
              Material('concrete', (0.8, 0.8, 0.8), 0.002), label='occluding post')
    sun_az, sun_el = rng.uniform(0.0, 2.0 * np.pi), np.deg2rad(rng.uniform(25.0, 60.0))
    b.decals(rng, 45, np.zeros(2), min(half, 20.0), 0.002, DECALS, [(np.zeros(2), 1.2)])
    light = np.array([np.cos(sun_az) * np.cos(sun_el), np.sin(sun_az) * np.cos(sun_el),
                      np.sin(sun_el)])
    return b.build('outdoor_cube', seed, variant, light, 0.35, 0.85, outdoor=True)


def _buildings(b: SceneBuilder, rng: np.random.Generator) -> None:
    """Facades 30-45 m away all around, windows on the side that faces the plaza."""
    count = int(rng.integers(5, 8))
    for k in range(count):
        az = 2.0 * np.pi * (k + rng.uniform(-0.25, 0.25)) / count
        r = rng.uniform(32.0, 45.0)
        width, depth = rng.uniform(12.0, 24.0), rng.uniform(8.0, 14.0)
        height = rng.uniform(6.0, 16.0)
        centre = np.array([(r + depth / 2) * np.cos(az), (r + depth / 2) * np.sin(az), height / 2])
        mat = FACADES[rng.integers(len(FACADES))]
        # Only the front and the sides can be seen from the plaza.
        b.box(centre, [depth, width, height], az, mat, label=f'building {k}', pairs=False,
              skip=(1, 4, 5))
        R = rot_z(az)
        storeys = min(4, max(1, int(height // 3.2)))
        for i in range(storeys):  # one ribbon window per storey
            z = (i + 0.5) * height / storeys
            y0, y1 = -width / 2 + 1.0, width / 2 - 1.0
            local = np.array([[-depth / 2 - 0.04, y0, z - 0.7], [-depth / 2 - 0.04, y1, z - 0.7],
                              [-depth / 2 - 0.04, y1, z + 0.7], [-depth / 2 - 0.04, y0, z + 0.7]])
            pts = np.array([centre[0], centre[1], 0.0]) + local @ R.T
            b.face(pts, WINDOW, toward_m=[0.0, 0.0, 1.5])


def _free_spot(rng: np.random.Generator, placed: list[tuple[FloatArray, float]], radius: float,
               r_range: tuple[float, float], az_range: tuple[float, float] | None,
               avoid: tuple[float, float] | None) -> FloatArray | None:
    """A ground position not overlapping placed objects and outside the camera sector."""
    for _ in range(50):
        r = rng.uniform(*r_range)
        az = rng.uniform(*az_range) if az_range else rng.uniform(0.0, 2.0 * np.pi)
        if avoid is not None and r < 28.0:
            rel = (az - avoid[0]) % (2.0 * np.pi)
            if rel < avoid[1] - avoid[0]:
                continue
        pos = r * np.array([np.cos(az), np.sin(az)])
        if all(np.linalg.norm(pos - p) > radius + q for p, q in placed):
            placed.append((pos, radius))
            return pos
    return None


def _random_object(b: SceneBuilder, rng: np.random.Generator,
                   placed: list[tuple[FloatArray, float]], sector: tuple[float, float],
                   k: int) -> None:
    """Crates, blocks, bins, bushes, cars, pallets, posts: texture and parallax for SfM."""
    kind = rng.choice(['crate', 'block', 'bin', 'bush', 'car', 'pallet', 'post'])
    size = {'crate': [1.0, 1.0, 0.9], 'block': [1.2, 0.6, 0.6], 'bin': [0.7, 0.7, 1.1],
            'bush': [1.8, 1.6, 1.3], 'car': [4.3, 1.8, 1.45], 'pallet': [1.2, 0.8, 0.15],
            'post': [0.15, 0.15, 4.0]}[kind] * rng.uniform(0.8, 1.25, size=3)
    pos = _free_spot(rng, placed, 0.5 * float(np.hypot(size[0], size[1])), (5.0, 25.0), None,
                     sector)
    if pos is None:
        return
    mat = {'crate': Material('cardboard', (1.0, 1.0, 1.0), 0.0015),
           'block': Material('concrete', (1.0, 1.0, 1.0), 0.001),
           'bin': Material('concrete', NEUTRAL_PAINTS[rng.integers(len(NEUTRAL_PAINTS))], 0.002),
           'bush': Material('foliage', (1.0, 1.0, 1.0), 0.003),
           'car': Material('cardboard', NEUTRAL_PAINTS[rng.integers(len(NEUTRAL_PAINTS))],
                           0.004),
           'pallet': Material('wood_dark', (1.1, 1.0, 0.9), 0.0015),
           'post': Material('concrete', (0.7, 0.7, 0.7), 0.002)}[kind]
    b.box([pos[0], pos[1], size[2] / 2], size, rng.uniform(0, np.pi), mat, label=f'{kind} {k}')


def _distractors(b: SceneBuilder, rng: np.random.Generator,
                 placed: list[tuple[FloatArray, float]], approach: float) -> None:
    """Red / yellow / purple objects and white boards behind the cube, as seen on approach."""
    behind = (approach + np.pi - 1.0, approach + np.pi + 1.0)
    for colour, size in (('red', [1.6, 0.9, 0.7]), ('yellow', [2.0, 0.4, 1.0]),
                         ('purple', [0.6, 0.6, 0.6]), ('red', [0.5, 0.5, 1.0])):
        pos = _free_spot(rng, placed, 0.6 * float(np.hypot(size[0], size[1])), (3.0, 14.0),
                         behind, None)
        if pos is None:
            continue
        b.box([pos[0], pos[1], size[2] / 2], size, rng.uniform(0, np.pi),
              targets.paint(colour), label=f'{colour} distractor')
        b.distractors.append({'kind': 'box', 'colour': colour, 'size_m': list(size),
                              'centre_world_m': [pos[0], pos[1], size[2] / 2]})
    for size in ([1.0, 0.7], [0.6, 0.45]):
        pos = _free_spot(rng, placed, 0.8, (2.5, 10.0), behind, None)
        if pos is None:
            continue
        centre = np.array([pos[0], pos[1], 0.004])
        corners = targets.rectangle(centre, rng.uniform(0, np.pi), size[0], size[1])
        b.face(corners, targets.PAPER, toward_m=centre + [0.0, 0.0, 5.0])
        b.distractors.append({'kind': 'white_rectangle', 'colour': 'white', 'size_m': size,
                              'centre_world_m': centre.tolist()})
