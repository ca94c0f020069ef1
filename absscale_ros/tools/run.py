"""``absscale run BAG --config CONFIG --out DIR``: the whole graph over a bag, outputs in DIR."""
import argparse
import json
from pathlib import Path
import sys
from typing import Any, Callable, TYPE_CHECKING

from absscale_ros import bagio, params

if TYPE_CHECKING:
    from absscale_ros import graph


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
    parser.add_argument('--live', action='store_true',
                        help='replay at bag rate into sensor-data QoS; nodes drop when behind '
                             '(use with --processes: one process cannot keep up at 1x)')
    parser.add_argument('--processes', action='store_true',
                        help='each node in its own process, talking over DDS on loopback')
    parser.add_argument('--split', action='store_true',
                        help='offline, experimental: the frame nodes (ingest, detector, '
                             'keyframe selector) and the sfm each in a process of their own, '
                             'so a run uses two cores (default: every node in this process)')
    parser.add_argument('--quiet', action='store_true', help='no progress bar')


def _progress_line(p: 'graph.Progress') -> str:
    width = 30
    filled = int(width * p.published / max(1, p.total))
    scale = 'scale: not yet' if p.scale is None else \
        f'scale {p.scale[0]:.5g} +/- {p.scale[1]:.2g}'
    return (f'\r[{"#" * filled}{"." * (width - filled)}] {p.published}/{p.total} msgs, '
            f'{p.steps} frames, {p.keyframes} keyframes, {scale}, {p.elapsed_s:.1f} s ')


def _against_truth(bag: str, report: dict[str, Any], latest: dict[str, Any]) -> dict[str, Any]:
    """The scale error against a simulator bag's gt.json ({} when there is none)."""
    from absscale_ros.tools import bench_scale
    try:  # simulator bags only; a stale or broken gt.json must not lose the run's outputs
        return bench_scale.against_truth_file(bag, report, latest)
    except Exception as err:  # noqa: BLE001 (an optional evaluation after the run)
        print(f'absscale run: not compared with {bag}.gt.json: {err}', file=sys.stderr)
        return {}


def run_with_outputs(bag: str, config: str, options: 'graph.RunOptions', out: Path,
                     on_progress: Callable[['graph.Progress'], None] | None = None
                     ) -> tuple[dict[str, Any], dict[str, Any]]:
    """
    The graph over ``bag``, then its output files in ``out``, with ``run.png`` drawn by a
    process started before the run and the comparison with ground truth made while it draws.

    :returns: the run's report (with its ``outputs``) and ``_against_truth``'s result.
    """
    from absscale_ros import graph, outputs
    picture = outputs.Picture()  # loads matplotlib while the graph starts
    try:
        report = graph.run_graph(bag, config, options, on_progress=on_progress)
        if on_progress is not None:
            print(file=sys.stderr)
        latest = report.pop('_latest')
        truth: dict[str, Any] = {}
        report['outputs'] = outputs.write_run_outputs(
            latest, out, report, picture,
            meanwhile=lambda: truth.update(_against_truth(bag, report, latest)))
    finally:
        picture.close()
    return report, truth


def run(args: argparse.Namespace) -> int:
    from absscale_ros import graph  # rclpy only once the arguments are good
    params.find_config(args.config)  # a bad config fails before the graph starts
    with bagio.BagReader(args.bag):
        pass  # a bad bag fails here with its one-line reason
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    show = None if args.quiet or not sys.stderr.isatty() else (
        lambda p: print(_progress_line(p), end='', file=sys.stderr, flush=True))
    if args.live and not args.processes:  # measured: 7-10 % of frames lost, p95 ~4 s
        print('absscale run: --live in one process: every node shares one Python interpreter '
              'and falls behind a 30 fps camera on 2 cores; add --processes for real time',
              file=sys.stderr)
    options = graph.RunOptions(mode=args.mode, rate=args.rate, live=args.live,
                               domain_id=args.domain_id, record=args.record,
                               processes=args.processes, split=args.split)
    report, truth = run_with_outputs(args.bag, args.config, options, out, show)
    if truth.get('scale_error_mm_per_m') is not None:
        report['truth'] = {k: truth[k] for k in ('true_factor', 'scale_error_mm_per_m',
                                                 'claimed_sigma_mm_per_m')}
    (out / 'report.json').write_text(json.dumps(report, indent=2, default=str) + '\n')
    print(f'replayed {report["replay"]["published"]} messages '
          f'({report["replay"]["steps"]} frames) in {report["wall_time_s"]:.1f} s; '
          f'report: {out / "report.json"}')
    scale = report['nodes'].get('scale')
    if scale is not None and not scale.get('observable'):
        print(f'absscale run: no metric scale established: {scale.get("reason")}',
              file=sys.stderr)
        return 1
    if scale is not None:
        print(f'metric scale: {scale["factor"]:.6g} m per SfM unit +/- '
              f'{1000 * scale["sigma"] / scale["factor"]:.2f} mm/m')
    if 'truth' in report:
        print(f'error against the bag\'s ground truth: '
              f'{report["truth"]["scale_error_mm_per_m"]:+.2f} mm/m')
    return 0
