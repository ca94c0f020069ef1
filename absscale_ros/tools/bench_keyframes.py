"""
``absscale bench keyframes BAG...``: keyframe selection against the simulator's gt.json.

Runs the core selector over every frame of each bag (decode excluded from the timing), then
reports per bag: keyframe count; for each consecutive keyframe pair the ground-truth baseline
over the median scene depth seen from the first keyframe, and whether it lies in the
configured band (pairs across a tracking loss are reported apart); keyframes inside a
pure-rotation segment (its first frame excluded: it may start one); motion blur of the chosen
frames; time per frame.
"""
import argparse
from dataclasses import fields
import json
import time
from typing import Any

import numpy as np

from absscale_ros import bagio, conversions, params
from absscale_ros.core import keyframe_geometry, keyframes
from absscale_ros.core.types import CameraModel

IMAGE_TYPES = ('sensor_msgs/msg/CompressedImage', 'sensor_msgs/msg/Image')


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('bags', nargs='+', metavar='BAG', help='bags with BAG.gt.json beside')
    parser.add_argument('--config', default='auto',
                        help='config whose keyframe_selector section sets the thresholds')
    parser.add_argument('--target-area', choices=('gt', 'none'), default='gt',
                        help='target size per frame from gt.json (as the detector would '
                             'report it) or none (frames alone)')
    parser.add_argument('--json', action='store_true', help='print the figures as JSON')


def config_from(config: str) -> keyframes.KeyframeConfig:
    """The KeyframeConfig of a config file's ``keyframe_selector`` section."""
    section = params.node_params(params.load_yaml(params.find_config(config)),
                                 'keyframe_selector')
    names = {f.name for f in fields(keyframes.KeyframeConfig)}
    return keyframes.KeyframeConfig(**{k: v for k, v in section.items() if k in names})


def select(bag: str, cfg: keyframes.KeyframeConfig, areas: dict[int, float] | None = None,
           cpu_ms: list[float] | None = None) -> tuple[list[keyframes.Decision], list[float]]:
    """
    Run the selector over a bag's frames, as the node does after ``frame_ingest``.

    :param areas: stamp (ns) -> target area fraction; None: no target information.
    :returns: one decision per frame and the wall time of each update, ms (process CPU time
        goes to ``cpu_ms`` when a list is passed: on a shared machine wall time overstates).
    """
    selector = keyframes.KeyframeSelector(cfg)
    decisions, times_ms = [], []
    camera: CameraModel | None = None
    with bagio.open_bag(bag) as reader:
        topics = reader.topics
        image_topic = next(t for t, i in topics.items() if i.msgtype in IMAGE_TYPES)
        info_topics = [t for t, i in topics.items() if i.msgtype.endswith('/CameraInfo')]
        for msg in reader.messages([image_topic, *info_topics]):
            ros = reader.deserialize(msg)
            if msg.topic != image_topic:
                camera = conversions.camera_info_to_model(ros)
                continue
            image = (conversions.compressed_msg_to_bgr(ros) if hasattr(ros, 'format')
                     else conversions.image_msg_to_bgr(ros))
            h, w = image.shape[:2]
            cam = camera if camera is not None and (camera.width, camera.height) == (w, h) \
                else keyframe_geometry.nominal_camera(w, h)
            stamp = conversions.stamp_to_ns(ros.header.stamp)
            t0, c0 = time.perf_counter(), time.process_time()
            decisions.append(selector.update(stamp, image, cam, (areas or {}).get(stamp, 0.0)))
            times_ms.append(1e3 * (time.perf_counter() - t0))
            if cpu_ms is not None:
                cpu_ms.append(1e3 * (time.process_time() - c0))
    return decisions, times_ms


def gt_areas(gt: dict[str, Any]) -> dict[int, float]:
    """stamp -> largest target area fraction of each frame (0 when no target is visible)."""
    return {int(f['stamp_ns']): max([t.get('area_fraction', 0.0) for t in f.get('targets', [])]
                                    or [0.0]) for f in gt['frames']}


def median_depth_m(gt: dict[str, Any], index: int) -> float:
    """Median z-depth of the scene seen from frame ``index``, m (sky excluded)."""
    frame = gt['frames'][index]
    if 'median_depth_m' in frame:
        return float(frame['median_depth_m'])
    from absscale_ros.sim import groundtruth  # the simulator's ray caster, only when needed
    depth = groundtruth.depth_map(gt, index)
    return float(np.nanmedian(depth[::8, ::8]))


def evaluate(gt: dict[str, Any], decisions: list[keyframes.Decision],
             cfg: keyframes.KeyframeConfig) -> dict[str, Any]:
    """Compare the keyframes of ``decisions`` with the ground truth (see the module docstring)."""
    index = {int(f['stamp_ns']): k for k, f in enumerate(gt['frames'])}
    kf = [d for d in decisions if d.keyframe]
    kf_idx = [index[d.stamp_ns] for d in kf]
    centres = {k: np.array(gt['frames'][k]['T_world_cam'])[:3, 3] for k in kf_idx}
    pairs = []
    for (a, b), d in zip(zip(kf_idx, kf_idx[1:]), kf[1:]):
        ratio = float(np.linalg.norm(centres[b] - centres[a]) / median_depth_m(gt, a))
        pairs.append({'frames': [a, b], 'gt_ratio': round(ratio, 4),
                      'estimated_ratio': round(d.baseline_ratio, 4),
                      'tracking_lost': d.after_loss,
                      'in_band': cfg.min_baseline_ratio <= ratio <= cfg.max_baseline_ratio})
    inside = [k for k in kf_idx for a, b in gt.get('pure_rotation_segments', []) if a < k <= b]
    blur = [float(gt['frames'][k].get('motion_blur_px', 0.0)) for k in kf_idx]
    return {'frames': len(decisions), 'keyframes': len(kf), 'keyframe_frames': kf_idx,
            'pairs': pairs, 'pairs_out_of_band': [p for p in pairs if not p['in_band']
                                                  and not p['tracking_lost']],
            'pairs_across_tracking_loss': sum(p['tracking_lost'] for p in pairs),
            'keyframes_in_pure_rotation': inside,
            'keyframe_blur_px_max': max(blur, default=0.0),
            'keyframe_sharpness_ratio_min': min((d.sharpness_ratio for d in kf), default=1.0),
            'band': [cfg.min_baseline_ratio, cfg.max_baseline_ratio]}


def run(args: argparse.Namespace) -> int:
    cfg = config_from(args.config)
    results, all_ms, all_cpu = {}, [], []  # type: ignore[var-annotated]
    for bag in args.bags:
        gt = json.loads(open(f'{bag}.gt.json').read())
        cpu_ms: list[float] = []
        decisions, times_ms = select(bag, cfg, gt_areas(gt) if args.target_area == 'gt'
                                     else None, cpu_ms)
        res = evaluate(gt, decisions, cfg)
        res['time_ms_median'] = float(np.median(times_ms))
        res['time_ms_p95'] = float(np.percentile(times_ms, 95))
        res['cpu_ms_median'] = float(np.median(cpu_ms))
        res['image_size'] = [gt['camera']['width'], gt['camera']['height']]
        results[bag] = res
        all_ms += times_ms
        all_cpu += cpu_ms
    total = {'bags': len(results), 'time_ms_median': float(np.median(all_ms)),
             'cpu_ms_median': float(np.median(all_cpu)),
             'keyframes_in_pure_rotation': sum(len(r['keyframes_in_pure_rotation'])
                                               for r in results.values()),
             'pairs': sum(len(r['pairs']) for r in results.values()),
             'pairs_out_of_band': sum(len(r['pairs_out_of_band']) for r in results.values()),
             'pairs_across_tracking_loss': sum(r['pairs_across_tracking_loss']
                                               for r in results.values())}
    if args.json:
        print(json.dumps({'bags': results, 'total': total}, indent=2))
        return 0
    print(f'{"bag":<40} {"frames":>6} {"kf":>4} {"ratio min..max":>15} {"out":>4} '
          f'{"lost":>4} {"rot":>4} {"blur":>5} {"ms med":>7} {"ms p95":>7} {"cpu ms":>7}')
    for bag, r in results.items():
        ratios = [p['gt_ratio'] for p in r['pairs']] or [float('nan')]
        print(f'{bag[-40:]:<40} {r["frames"]:>6} {r["keyframes"]:>4} '
              f'{min(ratios):>7.3f}..{max(ratios):<6.3f} {len(r["pairs_out_of_band"]):>4} '
              f'{r["pairs_across_tracking_loss"]:>4} {len(r["keyframes_in_pure_rotation"]):>4} '
              f'{r["keyframe_blur_px_max"]:>5.1f} {r["time_ms_median"]:>7.2f} '
              f'{r["time_ms_p95"]:>7.2f} {r["cpu_ms_median"]:>7.2f}')
    print(f'band {cfg.min_baseline_ratio}..{cfg.max_baseline_ratio}; total: {total}')
    return 0
