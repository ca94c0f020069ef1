"""
SfM update time against map size (issue #6: median update <= 250 ms up to 300 keyframes).

``python test/bench/sfm_update_scaling.py BAG [--every 10] [--bucket 50]``: every ``--every``-th
frame of ``BAG`` is a keyframe (so a long bag gives hundreds, in one segment if it tracks),
with its ground-truth vertices (+0.3 px) when ``BAG.gt.json`` is beside it. Prints the CPU time
of ``IncrementalSfm.add_keyframe`` (one OpenCV thread; decoding outside) per bucket of map
size, the final batch, and the camera-centre RMSE after Sim(3). With ``--pythonpath A B`` it
runs itself once per path side by side (same load) and prints the buckets in one table, e.g.
the code at HEAD (a ``git worktree``) against the working tree. ``--set KEY=VALUE`` changes
the ``SfmConfig`` of every run; ``--config outdoor_cube`` starts from that config's sfm section
(its full-resolution refinement, ``refine.max_observations`` 600) instead of the core defaults.
``--prefetch`` times the update as the sfm node runs it on two cores: each keyframe's features
are detected on a second thread while the keyframe before it is mapped, and the update is the
mapping thread's CPU plus any wait for them (the feature detection, ~90 ms of the ~230 a
keyframe costs, leaves the update's path; the process's CPU is the same).

The 60 s bag (``/tmp/lead/bags/outdoor_cube_60s.mcap``) pans on the spot up to keyframe 36 (every
6th frame; its first map starts at 61) and its map was refused at 142 by the off-plane check
(``min_off_plane_support``) with the refused pose 2 mm from the truth: for a map of 300
keyframes, ``--every 4 --limit 400 --set min_off_plane_support=0 --bucket 100``. With that and
``max_velocity_change=0``, before / after iSAM2 ordered landmarks first and took held views as
one prior per landmark (both runs side by side, load ~14): median 291 / 308 / 410 ms CPU at
0-99 / 100-199 / 200-299 keyframes -> 286 / 274 / 262 (the 0-99 bucket is mostly the pan's
pending keyframes, map size 0); camera-centre RMSE 0.090 -> 0.045 %.
"""
import argparse
from concurrent.futures import ThreadPoolExecutor
import itertools
import json
import os
import subprocess
import sys
import time
from typing import Any

import cv2
import numpy as np


def config(settings: list[str], name: str | None = None) -> Any:
    """``SfmConfig()`` (or config ``name``'s sfm section) with ``KEY=VALUE`` settings
    (``graph.window=6``: a stage's field, prefixed as in the config files)."""
    from dataclasses import replace
    from absscale_ros.core import sfm
    from absscale_ros.tools import bench_sfm
    cfg = bench_sfm._config(argparse.Namespace(config=name))
    stages = sfm.PARAM_PREFIXES
    for item in settings:
        key, value = item.split('=', 1)
        stage, _, name = key.rpartition('.')
        owner = getattr(cfg, stages[stage]) if stage else cfg
        old = getattr(owner, name)
        new = (value == 'true') if isinstance(old, bool) else type(old)(value)
        cfg = replace(cfg, **{stages[stage]: replace(owner, **{name: new})}) if stage else \
            replace(cfg, **{name: new})
    return cfg


def run(bag: str, every: int, limit: int, settings: list[str], name: str | None = None,
        prefetch: bool = False) -> dict:
    from absscale_ros.core import sfm
    from absscale_ros.tools import bench_sfm
    cv2.setNumThreads(1)
    args = argparse.Namespace(keyframes_from=None, select=False, every=every)
    camera, gt, frames = bench_sfm._from_bag(bag, args)
    engine = sfm.IncrementalSfm(camera, config(settings, name), np.random.default_rng(0))
    rng = np.random.default_rng(0)
    rows, poses, truth = [], {}, {}
    items = itertools.islice(frames, limit)
    item = next(items, None)
    # --prefetch: as the sfm node does, a keyframe's features are detected on a second thread
    # while the keyframe before it is mapped; its update is this thread's CPU plus any wait.
    pool = ThreadPoolExecutor(1) if prefetch else None
    ahead = pool.submit(engine.detect, item[1]) if pool is not None and item else None
    for kf_id in itertools.count():
        if item is None:
            break
        stamp, img, T, fr = item
        vertices, truth[kf_id] = bench_sfm._vertices(fr, gt, rng, 0.3)
        poses[kf_id] = T
        item = next(items, None)  # decoded outside the timing
        if pool is None:
            c0 = time.process_time()
            r = engine.add_keyframe(stamp, img, vertices)
            ms = 1e3 * (time.process_time() - c0)
        else:
            w0 = time.perf_counter()
            features = ahead.result()
            wait = time.perf_counter() - w0
            ahead = pool.submit(engine.detect, item[1]) if item else None
            c0 = time.thread_time()
            r = engine.add_keyframe(stamp, img, vertices, features=features)
            ms = 1e3 * (time.thread_time() - c0 + wait)
        rows.append((r.keyframes, ms, r.status))
        print(kf_id, *rows[-1], file=sys.stderr, flush=True)  # progress
    if pool is not None:
        pool.shutdown()  # its idle thread would otherwise outlive the run (several trees)
    c0 = time.process_time()
    engine.finish()
    finish_ms = 1e3 * (time.process_time() - c0)
    score = bench_sfm.score(engine, poses, truth, gt)
    return {'rows': rows, 'finish_ms': finish_ms,
            **{k: score.get(k) for k in ('segments', 'registered', 'landmarks',
                                         'centre_rmse_pct', 'reprojection_rms_px', 'vertices')}}


def buckets(rows: list, size: int) -> dict[int, tuple[int, float, float]]:
    """Map size bucket (keyframes of the current segment, floor to ``size``) -> count,
    median and 95th percentile update CPU ms."""
    out = {}
    kf = np.array([r[0] for r in rows])
    ms = np.array([r[1] for r in rows])
    for b in range(0, int(kf.max(initial=0)) + 1, size):
        sel = ms[(kf >= b) & (kf < b + size)]
        if len(sel):
            out[b] = (len(sel), float(np.median(sel)), float(np.percentile(sel, 95)))
    return out


def table(results: dict[str, dict], size: int, what: str = 'update CPU ms') -> str:
    lines = [f'{"map keyframes":<14}' + ''.join(f'{name[-24:]:>36}' for name in results),
             f'{"":<14}' + f'{"n   median  p95 " + what:>36}' * len(results)]
    bs = [buckets(r['rows'], size) for r in results.values()]
    for b in sorted(set().union(*bs)):
        cells = ''.join(f'{"":>36}' if b not in x else
                        f'{x[b][0]:>22} {x[b][1]:>6.0f} {x[b][2]:>6.0f}' for x in bs)
        lines.append(f'{b:>4}-{b + size - 1:<9}' + cells)
    for key in ('all', 'finish_ms', 'segments', 'registered', 'landmarks', 'centre_rmse_pct',
                'reprojection_rms_px', 'vertices'):
        vals = []
        for r in results.values():
            ms = np.array([x[1] for x in r['rows']])
            v = (f'{len(ms)} {np.median(ms):.0f} {np.percentile(ms, 95):.0f} '
                 f'(total {ms.sum() / 1e3:.1f} s)') if key == 'all' else r.get(key)
            vals.append(f'{v:.4g}' if isinstance(v, float) else str(v))
        lines.append(f'{key:<14}' + ''.join(f'{v:>36}' for v in vals))
    return '\n'.join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('bag')
    parser.add_argument('--every', type=int, default=10, help='keyframe = every Nth frame')
    parser.add_argument('--limit', type=int, default=10**9, help='stop after N keyframes')
    parser.add_argument('--bucket', type=int, default=50, help='map-size bucket, keyframes')
    parser.add_argument('--pythonpath', nargs='+', default=[],
                        help='run once per PYTHONPATH (in parallel) and compare')
    parser.add_argument('--json', action='store_true', help='print the raw result as JSON')
    parser.add_argument('--set', nargs='+', default=[], metavar='KEY=VALUE',
                        help='SfmConfig settings for every run, e.g. min_off_plane_support=0 '
                             '(see above) or graph.window=6')
    parser.add_argument('--prefetch', action='store_true',
                        help='detect each keyframe\'s features on a second thread while the one '
                             'before it is mapped, as the sfm node does (the update: this '
                             'thread\'s CPU plus any wait for them)')
    parser.add_argument('--config', default=None,
                        help="start from this config's sfm section (e.g. outdoor_cube: with "
                             "its full-resolution refinement) instead of the core defaults")
    args = parser.parse_args(argv)
    what = 'thread CPU+wait ms' if args.prefetch else 'update CPU ms'
    if not args.pythonpath:
        result = run(args.bag, args.every, args.limit, args.set, args.config, args.prefetch)
        print(json.dumps(result) if args.json else table({args.bag: result}, args.bucket, what))
        return 0
    cmd = [sys.executable, os.path.abspath(__file__), args.bag, '--every', str(args.every),
           '--limit', str(args.limit), '--json'] + (['--set', *args.set] if args.set else []) + \
        (['--config', args.config] if args.config else []) + \
        (['--prefetch'] if args.prefetch else [])
    procs = {p: subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True,
                                 env={**os.environ, 'PYTHONPATH': p, 'OMP_NUM_THREADS': '1'})
             for p in args.pythonpath}
    results = {p: json.loads(proc.communicate()[0]) for p, proc in procs.items()}
    print(table(results, args.bucket, what))
    return 0


if __name__ == '__main__':
    sys.exit(main())
