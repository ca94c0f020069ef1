"""``absscale run BAG --config CONFIG --out DIR``: the whole graph over a bag, outputs in DIR."""
import argparse
import json
from pathlib import Path
import sys

from absscale_ros import bagio, params


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('bag', help='rosbag2 folder or .mcap file')
    parser.add_argument('--config', default='auto',
                        help=f'one of {", ".join(params.CONFIG_NAMES)} or a YAML path')
    parser.add_argument('--out', default='out', help='output folder (created)')
    parser.add_argument('--mode', choices=('step', 'rate', 'fast'), default='step',
                        help='step: lossless and deterministic (default); rate: bag timing')
    parser.add_argument('--rate', type=float, default=1.0, help='speed factor in rate mode')
    parser.add_argument('--domain-id', type=int, default=None,
                        help='DDS domain to run on (default: a private one per run; give '
                             'your ROS_DOMAIN_ID to watch the run in RViz or Foxglove)')
    parser.add_argument('--record', metavar='OUT.mcap', default=None,
                        help='record every /absscale topic, /scaled_cloud and /diagnostics')
    parser.add_argument('--quiet', action='store_true', help='no progress bar')


def _progress_line(p: object) -> str:
    published, total = getattr(p, 'published'), max(1, getattr(p, 'total'))
    width = 30
    filled = int(width * published / total)
    return (f'\r[{"#" * filled}{"." * (width - filled)}] {published}/{total} msgs '
            f'{getattr(p, "steps")} frames {getattr(p, "elapsed_s"):.1f} s')


def run(args: argparse.Namespace) -> int:
    from absscale_ros import graph  # rclpy only once the arguments are good
    params.find_config(args.config)  # a bad config fails before the graph starts
    with bagio.BagReader(args.bag):
        pass  # a bad bag fails here with its one-line reason
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    show = None if args.quiet or not sys.stderr.isatty() else (
        lambda p: print(_progress_line(p), end='', file=sys.stderr, flush=True))
    report = graph.run_graph(args.bag, args.config,
                             replay_overrides={'mode': args.mode, 'rate': args.rate},
                             on_progress=show, domain_id=args.domain_id,
                             record=args.record)
    if show is not None:
        print(file=sys.stderr)
    from absscale_ros import outputs
    report['outputs'] = outputs.write_run_outputs(report.pop('_latest'), out, report)
    (out / 'report.json').write_text(json.dumps(report, indent=2, default=str) + '\n')
    print(f'replayed {report["replay"]["published"]} messages '
          f'({report["replay"]["steps"]} frames) in {report["wall_time_s"]:.1f} s; '
          f'report: {out / "report.json"}')
    return 0
