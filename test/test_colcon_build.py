"""The package builds with colcon as an ament_python package, as on a full ROS 2 install."""
import os
from pathlib import Path
import shutil
import subprocess
import sys

import pytest

ROOT = Path(__file__).resolve().parent.parent


def test_colcon_build_installs_nodes_config_and_marker(tmp_path: Path) -> None:
    colcon = Path(sys.executable).parent / 'colcon'
    if not colcon.exists():
        pytest.skip(f'colcon not installed next to {sys.executable} (make setup installs it)')
    src = tmp_path / 'src' / 'absscale_ros'
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(
        '.venv', '.git', 'build', 'install', 'log', '*.egg-info', '__pycache__', 'bags', 'out'))
    env = dict(os.environ, PATH=f'{colcon.parent}:{os.environ["PATH"]}')
    done = subprocess.run([str(colcon), 'build', '--event-handlers', 'console_direct-'],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    install = tmp_path / 'install' / 'absscale_ros'
    share = install / 'share' / 'absscale_ros'
    assert (install / 'share' / 'ament_index' / 'resource_index' / 'packages'
            / 'absscale_ros').exists()
    assert (share / 'package.xml').exists()
    assert {p.name for p in (share / 'config').glob('*.yaml')} >= {'indoor_paper.yaml',
                                                                   'outdoor_cube.yaml'}
    assert (share / 'launch' / 'absscale.launch.py').exists()
    scripts = {p.name for p in (install / 'lib' / 'absscale_ros').iterdir()}
    assert {'absscale', 'bag_replay'} <= scripts
    ran = subprocess.run([str(install / 'lib' / 'absscale_ros' / 'absscale'), '--help'],
                         capture_output=True, text=True, timeout=120, env=env)
    assert ran.returncode == 0 and 'bag info' in ran.stdout
