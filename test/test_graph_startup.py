"""What a run costs besides its nodes' work: the runner's imports."""
import json
import subprocess
import sys


def _run(code: str) -> dict:
    done = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_a_processes_runner_finds_its_nodes_without_importing_them() -> None:
    out = _run('import json, sys\n'
               'from absscale_ros import graph\n'
               'found = graph.available_modules({})\n'
               'print(json.dumps({"found": found, "imported": [m for _, m in found '
               'if m in sys.modules]}))')
    names = [name for name, _ in out['found']]
    assert names[:3] == ['frame_ingest', 'vertex_detector', 'keyframe_selector']
    assert 'dense' not in names  # only when the config enables it
    assert out['imported'] == []
