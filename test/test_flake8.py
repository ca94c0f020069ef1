"""House style (ament_flake8's rules that matter here): 99 columns, no unused names, pyflakes."""
from pathlib import Path
import subprocess
import sys

import pytest

ROOT = Path(__file__).resolve().parent.parent


def test_flake8_clean() -> None:
    if subprocess.run([sys.executable, '-m', 'flake8', '--version'],
                      capture_output=True).returncode != 0:
        pytest.skip('flake8 not installed (make setup installs it from requirements-dev.txt)')
    done = subprocess.run([sys.executable, '-m', 'flake8', '--max-line-length', '99',
                           'absscale_ros', 'test', 'launch', 'setup.py'],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-4000:]
