"""Scene registry: name + seed (+ variant) -> ``Scene``, deterministically."""
import numpy as np

from absscale_ros.sim import indoor, outdoor
from absscale_ros.sim.scene import Scene

SIM_VERSION = 2  # bump when the same name + seed + variant renders differently
SCENES = ('indoor_paper', 'outdoor_cube')
_INDOOR_TARGETS = (('letter', 'desk'), ('a4', 'desk'), ('letter', 'floor'),
                   ('letter', 'light_desk'))
_TOP_COLOURS = ('purple', 'red', 'yellow')


def streams(seed: int) -> dict[str, np.random.Generator]:
    """Independent random streams per concern, so adding draws to one leaves the others alone."""
    names = ('variant', 'scene', 'camera', 'trajectory', 'effects')
    children = np.random.SeedSequence(seed).spawn(len(names))
    return {n: np.random.default_rng(c) for n, c in zip(names, children)}


def default_variant(name: str, seed: int) -> dict[str, object]:
    """
    The variant a seed selects: the low digits cycle through targets / supports / top colours.

    indoor: seed % 4 -> letter on desk, A4 on desk, letter on floor, letter on a light desk;
    outdoor: seed % 3 -> purple, red, yellow on top. Distractors when (seed // 4) % 2 == 1,
    partial occlusion when (seed // 8) % 2 == 1.
    """
    check_name(name)
    flags = {'distractors': (seed // 4) % 2 == 1, 'occluded': (seed // 8) % 2 == 1}
    if name == 'indoor_paper':
        target, support = _INDOOR_TARGETS[seed % 4]
        return {'target': target, 'support': support, **flags}
    return {'target': 'cube', 'support': 'ground', 'top_colour': _TOP_COLOURS[seed % 3], **flags}


def check_name(name: str) -> None:
    """:raises ValueError: for an unknown scene name."""
    if name not in SCENES:
        raise ValueError(f'unknown scene {name!r}; known: {", ".join(SCENES)}')


def build_scene(name: str, seed: int, variant: dict[str, object] | None = None) -> Scene:
    """
    Build scene ``name`` for ``seed``; ``variant`` keys override the seed's default variant.

    :raises ValueError: for an unknown scene or variant value.
    """
    full = default_variant(name, seed)
    for key, value in (variant or {}).items():
        if key not in full:
            raise ValueError(f'unknown variant key {key!r} for {name}; known: {sorted(full)}')
        full[key] = value
    rng = streams(seed)['scene']
    if name == 'indoor_paper':
        if full['target'] not in ('letter', 'a4') or \
                full['support'] not in ('desk', 'floor', 'light_desk'):
            raise ValueError(f'bad indoor variant {full}')
        return indoor.build(seed, full, rng)
    if full['top_colour'] not in _TOP_COLOURS:
        raise ValueError(f'bad outdoor variant {full}')
    return outdoor.build(seed, full, rng)
