"""Test set-up: make test helpers importable, and skip ROS tests only on machines without rclpy."""
import importlib.util
from pathlib import Path
import sys

sys.path.insert(0, str(Path(__file__).resolve().parent))

if importlib.util.find_spec('rclpy') is None:  # a user's machine without ROS; never in CI
    print('rclpy not installed: skipping node and conversion tests')
    collect_ignore_glob = ['nodes/*', 'test_conversions*.py', 'test_bag*.py', 'test_cli*.py']
