"""`bench sfm --config` reads a config's sfm section as the sfm node does (no rclpy)."""
from dataclasses import fields, is_dataclass

from absscale_ros import params
from absscale_ros.core import sfm
import pytest

NODE_ONLY = {'pair_depth', 'seed', 'frame_id', 'use_tracked_steps', 'qos',
             'queue_keyframes', 'queue_worker', 'adjust_at_end'}  # not SfmConfig's


def _names(cfg: sfm.SfmConfig) -> set[str]:
    names = {f.name for f in fields(cfg) if not is_dataclass(getattr(cfg, f.name))}
    for prefix, attr in sfm.PARAM_PREFIXES.items():
        names |= {f'{prefix}.{f.name}' for f in fields(getattr(cfg, attr))}
    return names


@pytest.mark.parametrize('config', params.CONFIG_NAMES)
def test_every_sfm_parameter_of_a_config_reaches_the_core(config: str) -> None:
    flat = params.node_params(params.load_yaml(params.find_config(config)), 'sfm')
    unknown = set(flat) - _names(sfm.SfmConfig()) - NODE_ONLY
    assert not unknown  # a misspelt key would be silently ignored
    cfg = sfm.config_from_params(flat)
    for name, value in flat.items():
        if name in NODE_ONLY:
            continue
        prefix, _, leaf = name.rpartition('.')
        owner = getattr(cfg, sfm.PARAM_PREFIXES[prefix]) if prefix else cfg
        got = getattr(owner, leaf)
        assert (list(got) if isinstance(got, tuple) else got) == value, name


def test_the_scene_configs_differ_where_the_readme_says() -> None:
    def read(config: str) -> sfm.SfmConfig:
        return sfm.config_from_params(
            params.node_params(params.load_yaml(params.find_config(config)), 'sfm'))
    outdoor, indoor = read('outdoor_cube'), read('indoor_paper')
    assert outdoor.refine_cfg.max_observations > 0  # refined outdoors only
    assert indoor.refine_cfg.max_observations == 0
    assert indoor.min_pnp_inliers < outdoor.min_pnp_inliers
    assert sfm.config_from_params({}) == sfm.SfmConfig()
