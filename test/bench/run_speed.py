"""
Time ``absscale run`` on a bag for one or more code trees, interleaved, so that a shared,
noisy machine loads them alike (the ratio is the figure; absolute seconds drift with load).

  python test/bench/run_speed.py BAG --config outdoor_cube --tree base=/tmp/base \
      --tree new=. [--processes | --split] [--live] [--rounds 2]

Per run: wall time of the command, the replay's wall time and peak RSS from report.json, CPU
time of the run and its node processes, the factor and a hash of scaled_cloud.ply, and for
--live the frames each node dropped and the keyframe-to-/scaled_cloud latency. ``others_cpu_s``
is the CPU the rest of the machine used meanwhile (all cores' busy time from /proc/stat less
the run's own) and ``idle_core_s`` the cores' idle time: a run that shared the machine with
another busy job says so (session 14: two runs held to one core by another priority job took
51.6 and 57.3 s, the runs beside them 36.9 and 42.2 s), and on an idle machine the idle time
is what the run's layout left unused.
"""
import argparse
import hashlib
import json
import os
from pathlib import Path
import resource
import signal
import subprocess
import sys
import tempfile
import time


def _machine_cpu_s() -> tuple[float, float]:
    """
    (busy, idle) CPU seconds of all cores since boot (/proc/stat; iowait counts as idle).

    Busy is user + nice + system + irq + softirq: steal is time the hypervisor gave to others,
    and guest time is already inside user.
    """
    with open('/proc/stat') as f:
        ticks = [int(x) for x in f.readline().split()[1:]]
    busy = ticks[0] + ticks[1] + ticks[2] + ticks[5] + ticks[6]
    idle = ticks[3] + ticks[4]
    return busy / os.sysconf('SC_CLK_TCK'), idle / os.sysconf('SC_CLK_TCK')


def run_once(tree: Path, bag: str, config: str, extra: list[str]) -> dict:
    with tempfile.TemporaryDirectory(prefix='run_speed_') as out:
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        machine0 = _machine_cpu_s()
        t0 = time.monotonic()
        done = subprocess.run(
            [sys.executable, '-m', 'absscale_ros.cli', 'run', bag, '--config', config,
             '--out', out, '--quiet', *extra], cwd=tree, capture_output=True, text=True,
            env={**os.environ, 'PYTHONPATH': str(tree)},
            # As from a terminal: this bench is often a script's background job, whose SIGINT
            # is ignored, and trees before the reset in node_processes then waited 30 s per
            # node process at the end (and lost their reports).
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        wall = time.monotonic() - t0
        machine1 = _machine_cpu_s()
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        path = Path(out) / 'report.json'
        report = json.loads(path.read_text()) if path.exists() else {}
        cloud = Path(out) / 'scaled_cloud.ply'  # "identical cloud": the same bytes
        cloud_sha1 = hashlib.sha1(cloud.read_bytes()).hexdigest()[:12] if cloud.exists() else None
    nodes = report.get('nodes', {})
    cpu = after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime
    return {
        'exit': done.returncode, 'wall_s': round(wall, 1),
        'replay_s': report.get('wall_time_s'),
        'cpu_s': round(cpu, 1),
        'others_cpu_s': round(machine1[0] - machine0[0] - cpu, 1),
        'idle_core_s': round(machine1[1] - machine0[1], 1),
        'process_cpu_s': report.get('process_cpu_s'),  # per process: runner, node groups
        'peak_rss_mb': report.get('peak_rss_mb'),
        'frames_decoded': nodes.get('frame_ingest', {}).get('frames_decoded'),
        'frames_missing': nodes.get('frame_ingest', {}).get('frames_missing'),
        'detector_frames': nodes.get('vertex_detector', {}).get('frames'),
        'keyframes': nodes.get('keyframe_selector', {}).get('keyframes'),
        'sfm_keyframes_in': nodes.get('sfm', {}).get('keyframes_in'),
        'scale': nodes.get('scale', {}).get('factor'),
        'cloud_sha1': cloud_sha1,
        'steps_deferred': report.get('replay', {}).get('steps_deferred'),
        'latency_s': report.get('latency_s'),
        'last_line': (done.stdout.strip().splitlines() or [''])[-1][:200],
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('bag')
    parser.add_argument('--config', required=True)
    parser.add_argument('--tree', action='append', required=True,
                        help='NAME=PATH of a source tree (repeat; the first is the baseline)')
    parser.add_argument('--rounds', type=int, default=1)
    parser.add_argument('--processes', action='store_true')
    parser.add_argument('--split', action='store_true')
    parser.add_argument('--live', action='store_true')
    args = parser.parse_args()
    trees = [t.split('=', 1) for t in args.tree]
    extra = [f'--{flag}' for flag in ('processes', 'split', 'live') if getattr(args, flag)]
    results: dict[str, list[dict]] = {name: [] for name, _ in trees}
    for _ in range(args.rounds):
        for name, path in trees:
            res = run_once(Path(path).resolve(), str(Path(args.bag).resolve()), args.config,
                           extra)
            results[name].append(res)
            print(json.dumps({'tree': name, **res}), flush=True)
    base = trees[0][0]
    for name, _ in trees[1:]:
        ratio = [n['wall_s'] / b['wall_s'] for n, b in zip(results[name], results[base])]
        print(f'{name} / {base} wall time: ' + ', '.join(f'{r:.2f}' for r in ratio))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
