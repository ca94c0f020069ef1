"""What a run costs besides its nodes' work: the runner's imports, freed frame buffers."""
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


FRAMES = '''
import json, resource
import numpy as np
from absscale_ros.nodes import common
if {keep}:
    common.keep_freed_memory()
def faults():
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt
def step():  # a frame and two images made from it (a detector's), then all freed
    return [np.ones((720, 1280, 3), np.uint8) for _ in range(3)]
step()
before = faults()
for _ in range(20):
    step()
print(json.dumps({{'faults': faults() - before}}))
'''


def test_freed_frames_are_reused_without_the_kernel_zeroing_them_again() -> None:
    pages = 720 * 1280 * 3 // 4096  # 675 pages an image
    fresh = _run(FRAMES.format(keep=False))['faults']
    kept = _run(FRAMES.format(keep=True))['faults']
    # By default glibc trims the 8 MB freed at the heap's top after every step, and the
    # kernel zeroes the pages again at the next one.
    assert fresh >= 20 * pages
    assert kept < pages  # the same heap memory serves every step


def test_the_frame_nodes_start_without_scipy() -> None:
    """scipy.spatial takes 0.36 s of CPU to import, in every node process that imports it."""
    out = _run('import json, sys\n'
               'import absscale_ros.nodes.frame_ingest, absscale_ros.nodes.vertex_detector\n'
               'import absscale_ros.nodes.keyframe_selector\n'
               'print(json.dumps({"scipy": "scipy.spatial" in sys.modules}))')
    assert out == {'scipy': False}


def test_the_sfm_process_starts_without_scipy_stats() -> None:
    """scipy.stats took 0.9 s to import, on the path of every run's start (the replay waits
    for the scale node); the scale node's first estimate loads it."""
    out = _run('import json, sys\n'
               'import absscale_ros.nodes.sfm, absscale_ros.nodes.scale\n'
               'print(json.dumps({"stats": "scipy.stats" in sys.modules}))')
    assert out == {'stats': False}
