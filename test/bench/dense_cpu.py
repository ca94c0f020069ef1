"""
CPU (and wall) time per keyframe update of the dense core against a baseline tree,
interleaved keyframe by keyframe on the true poses (as ``absscale bench dense --gt-poses``
feeds it), so both see the same load: the ratio is the figure.

  python test/bench/dense_cpu.py --base /tmp/base_tree [--config C] [--base-config C] BAG...

The baseline's ``absscale_ros`` is copied under another package name (``detect_cpu.py``), so
both cores live in one process; each tree reads its own config (default: the scene's, from
that tree's config/). Prints per bag both trees' median and p95 update CPU and wall time and
the median of the per-keyframe ratios (wall: meaningful only beside a core that is free).
"""
import argparse
import importlib
from pathlib import Path
import sys
import tempfile
import time

import cv2
import numpy as np

from absscale_ros.sim import groundtruth
from absscale_ros.tools import bench_keyframes, dense_truth

sys.path.insert(0, str(Path(__file__).parent))
from detect_cpu import load_base  # noqa: E402  (the same copy of the base tree)


def _fusion(truth: object, config: str) -> object:
    fusion = importlib.import_module(truth.__name__.split('.')[0] + '.core.dense_fusion')
    return fusion.DenseFusion(*truth.dense_configs(config))


def _timed(fusion: object, stamp: int, image: np.ndarray, camera: object,
           poses: dict[int, np.ndarray]) -> tuple[float, float]:
    """CPU and wall seconds of one keyframe's update."""
    start, wall = time.process_time(), time.perf_counter()
    fusion.add_keyframe(stamp, image, camera)
    fusion.update(poses)
    fusion.cloud()
    return time.process_time() - start, time.perf_counter() - wall


def compare(bag: str, base_truth: object, configs: tuple[str, str]) -> dict[str, float]:
    """Median / p95 update CPU of the base and this tree on one bag, and the median ratio."""
    gt = groundtruth.load(f'{bag}.gt.json')
    decisions, _ = bench_keyframes.select(bag, bench_keyframes.config_from(configs[1]),
                                          bench_keyframes.gt_areas(gt))
    stamps = [d.stamp_ns for d in decisions if d.keyframe]
    images = dense_truth._keyframe_images(bag, set(stamps))
    index = {int(f['stamp_ns']): k for k, f in enumerate(gt['frames'])}
    camera = groundtruth.camera_from_json(gt['camera'])
    cores = (_fusion(base_truth, configs[0]), _fusion(dense_truth, configs[1]))
    poses: dict[int, np.ndarray] = {}
    times: tuple[list[tuple[float, float]], list[tuple[float, float]]] = ([], [])
    for k, s in enumerate(stamps):
        poses[s] = np.array(gt['frames'][index[s]]['T_world_cam'])
        order = (0, 1) if k % 2 == 0 else (1, 0)  # neither always runs first
        for which in order:
            times[which].append(_timed(cores[which], s, images[s], camera, poses))
    out = {}
    for kind, column in (('', 0), ('wall_', 1)):
        base = np.array([t[column] for t in times[0]])
        new = np.array([t[column] for t in times[1]])
        out |= {f'{kind}base_median': float(np.median(base)),
                f'{kind}base_p95': float(np.percentile(base, 95)),
                f'{kind}new_median': float(np.median(new)),
                f'{kind}new_p95': float(np.percentile(new, 95)),
                f'{kind}ratio_of_medians': float(np.median(new) / np.median(base)),
                f'{kind}median_ratio': float(np.median(new / np.maximum(base, 1e-9)))}
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('bags', nargs='+')
    parser.add_argument('--base', required=True, help='baseline source tree')
    parser.add_argument('--config', default=None, help="this tree's config (default: scene)")
    parser.add_argument('--base-config', default=None,
                        help="the base's config (default: the scene's in the base tree)")
    args = parser.parse_args(argv)
    cv2.setNumThreads(1)
    with tempfile.TemporaryDirectory() as tmp:
        load_base(Path(args.base), Path(tmp))
        base_truth = importlib.import_module('absscale_base.tools.dense_truth')
        for bag in args.bags:
            scene = str(groundtruth.load(f'{bag}.gt.json')['scene']['name'])
            configs = (args.base_config or str(Path(args.base) / 'config' / f'{scene}.yaml'),
                       args.config or scene)
            r = compare(bag, base_truth, configs)
            for kind, name in (('', 'CPU'), ('wall_', 'wall')):
                print(f'{bag}: update {name} median base {r[kind + "base_median"]:.2f} s -> '
                      f'{r[kind + "new_median"]:.2f} s (p95 {r[kind + "base_p95"]:.2f} -> '
                      f'{r[kind + "new_p95"]:.2f}); ratio of medians '
                      f'{r[kind + "ratio_of_medians"]:.3f}, median per-keyframe ratio '
                      f'{r[kind + "median_ratio"]:.3f}', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
