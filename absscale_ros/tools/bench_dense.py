"""
``absscale bench dense BAG...``: the dense cloud against the simulator's ground truth.

Default: the whole graph runs with the dense node on, and its metric trajectory is rigidly
aligned to the truth (a scale error counts). ``--gt-poses``: only the dense core, on the
keyframes the selector picks, with their true poses (stereo quality without SfM error).
Figures (issue 9): median / p90 distance to the true surface as a fraction of the median scene
depth, completeness within 2 cm (indoor) / 5 cm (outdoor), points against the sparse cloud,
update time per keyframe (CPU of the whole process, and wall; median and p95).
"""
import argparse
import json
from typing import Any

import numpy as np

TARGETS = 'median <= 0.3 %, p90 <= 1 % of depth; completeness >= 70 %; >= 20x sparse; <= 2 s'


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('bags', nargs='+', help='simulator bags (BAG.gt.json beside each)')
    parser.add_argument('--config', default=None, help='config (default: from the scene)')
    parser.add_argument('--gt-poses', action='store_true',
                        help='dense core alone on the true keyframe poses')
    parser.add_argument('--sample-step', type=int, default=24,
                        help='surface samples every this many pixels of each keyframe')
    parser.add_argument('--ply', default=None, help='write the dense cloud of the last bag here')
    parser.add_argument('--png', default=None, help='picture of the last bag\'s dense cloud')
    parser.add_argument('--json', action='store_true', help='one JSON object per bag')


def run(args: argparse.Namespace) -> int:
    from absscale_ros.tools import dense_truth
    print(f'targets: {TARGETS}')
    for bag in args.bags:
        result = dense_truth.evaluate_bag(bag, args.config, args.gt_poses, args.sample_step,
                                          args.ply, args.png)
        print(json.dumps(result) if args.json else _line(result), flush=True)
    return 0


def _by_depth(r: dict[str, Any]) -> str:
    """Completeness per fifth of the samples by depth: where a shortfall lies."""
    fifths = r.get('completeness_by_depth') or ()
    return ' (by depth fifth ' + ' / '.join(f'{100 * c:.0f}' for c in fifths) + ' %)' \
        if fifths else ''


def _line(r: dict[str, Any]) -> str:
    if 'error' in r:
        return f'{r["bag"]}: {r["error"]}'
    return (f'{r["bag"]}: {r["points"]} points ({r["sparse_ratio"]:.0f}x sparse) over '
            f'{r["keyframes"]} keyframes; depth {r["median_scene_depth_m"]:.2f} m; distance '
            f'median {100 * r["median_rel"]:.3f} % p90 {100 * r["p90_rel"]:.3f} % '
            f'({1000 * r["distance_median_m"]:.1f} / {1000 * r["distance_p90_m"]:.1f} mm); '
            f'completeness {100 * r["completeness"]:.1f} % of {r["surface_samples"]} samples '
            f'within {100 * r["radius_m"]:.0f} cm{_by_depth(r)}; update CPU median '
            f'{_s(r["update_s_median"])} s '
            f'(p95 {_s(r["update_s_p95"])}), wall {_s(r.get("update_wall_s_median"))} s '
            f'(p95 {_s(r.get("update_wall_s_p95"))})')


def _s(seconds: float | None) -> str:
    return f'{np.nan if seconds is None else seconds:.2f}'
