"""Broken bags: one clear line naming the file and the problem, non-zero exit, no traceback."""
import os
from pathlib import Path
import subprocess
import sys

from bagfactory import write_camera_bag
import pytest


def _absscale(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-m', 'absscale_ros.cli', *args],
                          capture_output=True, text=True, timeout=120)


def _unknown_type_bag(path: Path) -> None:
    from mcap.writer import Writer
    with path.open('wb') as f:
        writer = Writer(f)
        writer.start(profile='ros2')
        schema = writer.register_schema('acme_msgs/msg/Widget', 'ros2msg', b'int32 x\n')
        channel = writer.register_channel('/widget', 'cdr', schema)
        writer.add_message(channel, log_time=1, publish_time=1,
                           data=b'\x00\x01\x00\x00\x07\x00\x00\x00')
        writer.finish()


def _make(kind: str, tmp_path: Path) -> tuple[Path, str]:
    if kind == 'truncated':
        good = tmp_path / 'good.mcap'
        write_camera_bag(good, frames=3)
        bad = tmp_path / 'cut.mcap'
        bad.write_bytes(good.read_bytes()[:good.stat().st_size // 2])
        return bad, 'truncated'
    if kind == 'random':
        bad = tmp_path / 'noise.mcap'
        bad.write_bytes(os.urandom(4096))
        return bad, 'not a bag'
    if kind == 'no_metadata':
        bad = tmp_path / 'folder_bag'
        bad.mkdir()
        (bad / 'folder_bag_0.mcap').write_bytes(b'')
        return bad, 'no metadata.yaml'
    if kind == 'missing':
        return tmp_path / 'nowhere.mcap', 'no such file'
    bad = tmp_path / 'widget.mcap'
    _unknown_type_bag(bad)
    return bad, "unknown message type 'acme_msgs/msg/Widget'"


@pytest.mark.parametrize('kind', ['truncated', 'random', 'no_metadata', 'missing'])
@pytest.mark.parametrize('verb', [['bag', 'info'], ['run']])
def test_bad_bag_is_one_line_error(tmp_path: Path, kind: str, verb: list[str]) -> None:
    bag, reason = _make(kind, tmp_path)
    done = _absscale(*verb, str(bag), '--out', str(tmp_path / 'out')) if verb == ['run'] \
        else _absscale(*verb, str(bag))
    assert done.returncode == 1
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and 'Traceback' not in done.stderr, done.stderr
    assert str(bag) in lines[0] and reason in lines[0], lines[0]


def test_unknown_message_type_listed_by_info_refused_by_run(tmp_path: Path) -> None:
    bag, reason = _make('unknown_type', tmp_path)
    info = _absscale('bag', 'info', str(bag))
    assert info.returncode == 0 and 'acme_msgs/msg/Widget' in info.stdout
    done = _absscale('run', str(bag), '--out', str(tmp_path / 'out'))
    assert done.returncode == 1 and 'Traceback' not in done.stderr, done.stderr
    last = done.stderr.strip().splitlines()[-1]
    assert str(bag) in last and reason in last and '/widget' in last
