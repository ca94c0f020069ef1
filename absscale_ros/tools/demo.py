"""``absscale demo``: the graph on the sample bag shipped in bags/, with a plain summary."""
import argparse
import json
from pathlib import Path

from absscale_ros.core.errors import AbsScaleError

BAGS = Path(__file__).resolve().parent.parent.parent / 'bags'
SAMPLES = {'indoor_paper': 'indoor_paper_sample.mcap', 'outdoor_cube': 'outdoor_cube_sample.mcap'}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--scene', choices=sorted(SAMPLES), default='indoor_paper',
                        help='which sample bag to run')
    parser.add_argument('--out', default='out/demo', help='output folder')


def run(args: argparse.Namespace) -> int:
    from absscale_ros import graph
    bag = BAGS / SAMPLES[args.scene]
    if not bag.exists():
        raise AbsScaleError(f'{bag}: sample bag missing (a source checkout ships it in bags/)')
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    print(f'absscale demo: replaying {bag.name} through the graph (config {args.scene})')
    report = graph.run_graph(str(bag), args.scene, graph.RunOptions(mode='step'))
    from absscale_ros import outputs
    report['outputs'] = outputs.write_run_outputs(report.pop('_latest'), out, report)
    (out / 'report.json').write_text(json.dumps(report, indent=2, default=str) + '\n')
    replay = report['replay']
    print(f'  frames replayed : {replay["steps"]} ({replay["published"]} messages) in '
          f'{report["wall_time_s"]:.1f} s')
    print(f'  nodes running   : {", ".join(report["nodes"]) or "bag_replay only"}')
    for topic, count in report['messages_per_topic'].items():
        print(f'  {topic:<32}: {count} messages')
    scale = report.get('scale')
    if scale is None:
        print('  metric scale    : not established (the scale node is not built yet)')
    print(f'  report          : {out / "report.json"}')
    return 0
