"""
ROS parameter YAML files and config lookup (no rclpy).

A config file has one ``<node_name>: ros__parameters:`` section per node, as ``ros2 launch``
and ``--params-file`` expect; ``/**`` sections apply to every node.
"""
import os
from pathlib import Path
import sys
from typing import Any

from absscale_ros.core.errors import AbsScaleError
from absscale_ros.core.targets import SHEET_SIZES_M
import yaml

# libyaml's safe loader where PyYAML has it: 8 against 80 ms a config, read by every process of
# a run as it starts.
SAFE_LOADER = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)

CONFIG_NAMES = ('indoor_paper', 'outdoor_cube', 'auto')


def config_dirs() -> list[Path]:
    """Where named configs live: the source tree, then the installed share folder."""
    dirs = [Path(__file__).resolve().parent.parent / 'config',
            Path(sys.prefix) / 'share' / 'absscale_ros' / 'config']
    try:
        from ament_index_python.packages import get_package_share_directory
        dirs.append(Path(get_package_share_directory('absscale_ros')) / 'config')
    except Exception:  # no ament index: a pip install without ROS
        pass
    return dirs


def find_config(name_or_path: str) -> Path:
    """Return the YAML file for a config name (``indoor_paper``...) or an explicit path."""
    path = Path(name_or_path)
    if path.suffix in ('.yaml', '.yml') or path.exists():
        if not path.is_file():
            raise AbsScaleError(f'{path}: config file not found')
        return path
    for folder in config_dirs():
        candidate = folder / f'{name_or_path}.yaml'
        if candidate.is_file():
            return candidate
    raise AbsScaleError(f'unknown config {name_or_path!r}: use one of '
                        f'{", ".join(CONFIG_NAMES)} or a path to a YAML file')


DDS_PROFILE_VARIABLE = 'FASTRTPS_DEFAULT_PROFILES_FILE'


def dds_environment() -> dict[str, str]:
    """
    The Fast DDS profile for frames between processes (``config/fastdds_shm.xml``: a shared
    memory segment that holds a whole decoded frame), unless the user chose one already.
    """
    if os.environ.get(DDS_PROFILE_VARIABLE):
        return {}
    for folder in config_dirs():
        if (folder / 'fastdds_shm.xml').is_file():
            return {DDS_PROFILE_VARIABLE: str(folder / 'fastdds_shm.xml')}
    return {}


def load_yaml(path: Path) -> dict[str, dict[str, Any]]:
    """Return node name -> parameters; ``/**`` parameters merged under each node's own."""
    try:
        data = yaml.load(path.read_text(), Loader=SAFE_LOADER) or {}
    except yaml.YAMLError as err:
        raise AbsScaleError(f'{path}: not valid YAML: {err}') from err
    if not isinstance(data, dict):
        raise AbsScaleError(f'{path}: expected a mapping of node names')
    sections: dict[str, dict[str, Any]] = {}
    for node, body in data.items():
        params = (body or {}).get('ros__parameters') if isinstance(body, dict) else None
        if not isinstance(params, dict):
            raise AbsScaleError(f'{path}: section {node!r} has no ros__parameters mapping')
        sections[str(node).lstrip('/')] = _flatten(params)
    return sections


def _flatten(params: dict[str, Any], prefix: str = '') -> dict[str, Any]:
    """Nested mappings become dotted names (``sheet: {aspect_tol: 0.1}`` -> ``sheet.aspect_tol``),
    as ROS 2 reads a parameter file."""
    flat: dict[str, Any] = {}
    for key, value in params.items():
        name = f'{prefix}{key}'
        if isinstance(value, dict):
            flat.update(_flatten(value, name + '.'))
        else:
            flat[name] = value
    return flat


def node_params(sections: dict[str, dict[str, Any]], node: str) -> dict[str, Any]:
    """Parameters for ``node``: the ``/**`` defaults overridden by its own section."""
    merged = dict(sections.get('**', {}))
    merged.update(sections.get(node, {}))
    return merged


def detected_sheet(sections: dict[str, dict[str, Any]]) -> str:
    """
    The scale node's sheet under ``sheet: auto``: the one sheet the detector looks for, if it
    looks for one only ('auto' otherwise). Corners fit A4 just as well when they are an A5 or
    A6 card's (the same 1:sqrt(2) shape, half or a quarter the size): a detector looking for
    letter passed an A6 card on a light desk (aspect 1.29-1.39 measured, 8 % allowed) and
    'auto' scaled it as an A4 page, twice the truth with a 0.4 % sigma (s18 bag 63).
    """
    detector = node_params(sections, 'vertex_detector')
    target = detector.get('target', 'auto')
    if target in SHEET_SIZES_M and not detector.get('sheet.other_sheets'):
        return str(target)
    return 'auto'


def scale_sheet(sections: dict[str, dict[str, Any]]) -> dict[str, str]:
    """The scale node's ``sheet`` override of a run of ``sections`` ({} when it is not
    'auto'; ``absscale run`` and the launch file apply it)."""
    if node_params(sections, 'scale').get('sheet', 'letter') != 'auto':
        return {}
    return {'sheet': detected_sheet(sections)}
