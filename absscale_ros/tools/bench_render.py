"""
``absscale bench render``: simulator throughput, JPEG encoding and bag writing included.

Runs ``absscale simulate`` into a temporary folder for each scene and reports frames per second
of the frame loop (setup: scene, texture atlas and ray tables, is reported apart), the CPU time
per frame of this process (both cores count), and the load average, since other processes on a
shared machine slow it down.
"""
import argparse
import json
import logging
import os
from pathlib import Path
import tempfile

from absscale_ros.tools import simulate

LOG = logging.getLogger('absscale.bench_render')


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--scene', nargs='+', default=['indoor_paper', 'outdoor_cube'],
                        choices=('indoor_paper', 'outdoor_cube'))
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--frames', type=int, default=300,
                        help='frames per scene (300 = the default 10 s video)')
    parser.add_argument('--size', default='1280x720')
    parser.add_argument('--quality', type=int, default=90)
    parser.add_argument('--min-fps', type=float, default=0.0,
                        help='exit 1 when a scene renders slower than this')
    parser.add_argument('--json', type=Path, default=None, help='also write the figures here')


def run(args: argparse.Namespace) -> int:
    results = []
    with tempfile.TemporaryDirectory(prefix='absscale_bench_') as tmp:
        for scene in args.scene:
            sim_args = argparse.Namespace(
                scene=scene, seed=args.seed, out=Path(tmp) / f'{scene}.mcap', frames=args.frames,
                size=args.size, raw=False, format='jpeg', quality=args.quality, variant=[],
                image_topic=None, info_topic='/camera/camera_info', frame_id='camera',
                no_pipeline=False)
            load_before = os.getloadavg()[0]
            figures = simulate.simulate(sim_args)
            load_after = os.getloadavg()[0]
            size_mb = sim_args.out.stat().st_size / 1e6
            row = {'scene': scene, 'size': args.size, 'frames': args.frames,
                   'fps': round(figures['fps'], 2), 'loop_s': round(figures['loop_s'], 2),
                   'setup_s': round(figures['setup_s'], 2),
                   'cpu_ms_per_frame': round(1e3 * figures['loop_cpu_s'] / args.frames, 1),
                   'bag_mb': round(size_mb, 2),
                   'load_avg_1min': [round(load_before, 2), round(load_after, 2)]}
            results.append(row)
            print(f'{scene:<13} {args.size}: {row["fps"]:6.2f} frames/s  '
                  f'({args.frames} frames in {row["loop_s"]} s, setup {row["setup_s"]} s, '
                  f'{row["cpu_ms_per_frame"]} ms CPU/frame, bag {row["bag_mb"]} MB, '
                  f'1-min load average before/after {row["load_avg_1min"]})')
    if args.json is not None:
        args.json.write_text(json.dumps(results, indent=1) + '\n')
    slow = [r for r in results if r['fps'] < args.min_fps]
    return 1 if slow else 0
