"""Small simulated bags shared by the simulator tests (640x360, a few dozen frames)."""
import argparse
from pathlib import Path

import pytest

from absscale_ros.sim import groundtruth
from absscale_ros.tools import simulate


def sim_args(out: Path, scene: str, seed: int, frames: int, **kw: object) -> argparse.Namespace:
    """The arguments ``absscale simulate`` would parse."""
    base = dict(scene=scene, seed=seed, out=out, frames=frames, size='640x360', raw=False,
                format='jpeg', quality=90, variant=[], image_topic=None,
                info_topic='/camera/camera_info', frame_id='camera', no_pipeline=False)
    base.update(kw)
    return argparse.Namespace(**base)


@pytest.fixture(scope='session')
def outdoor_bag(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp('sim') / 'outdoor.mcap'
    simulate.simulate(sim_args(out, 'outdoor_cube', 3, 40))
    return out, groundtruth.load(simulate.gt_path(out))


@pytest.fixture(scope='session')
def indoor_bag(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp('sim') / 'indoor.mcap'
    simulate.simulate(sim_args(out, 'indoor_paper', 0, 40))
    return out, groundtruth.load(simulate.gt_path(out))
