"""
``absscale bench scale BAG...``: the metric scale and lengths of full runs against ground truth.

For each simulator bag (with ``BAG.gt.json`` beside it) the whole graph runs losslessly; then
the factor is compared with the one that best aligns the unscaled keyframe trajectory with the
true camera centres, and lengths between reconstructed landmarks with the lengths between their
true points (the paper's Table 3, in mm per metre). A landmark's true point is the surface
point behind its own observations (``evaluation.observed_truth``, the sfm's map read after the
run); ``lengths_projected`` keeps the figures against the older truth, the landmark projected
through the reconstructed keyframes (``evaluation.landmark_truth``). Where the error comes from
(``_decomposition``): the cloud's own scale error against its landmarks' truth, the lengths
without it, and the lengths of the same observations triangulated from the true poses.
"""
import argparse
import json
from pathlib import Path
import tempfile
from typing import Any

import numpy as np
import yaml

PAPER_TABLE3 = {'indoor': (107, 1.4, 4.2, 0.7), 'outdoor': (281, 3.7, 8.5, 1.8)}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('bags', nargs='+', help='simulator bags (BAG.gt.json beside each)')
    parser.add_argument('--config', default=None, help='config (default: from the scene)')
    parser.add_argument('--json', action='store_true', help='print one JSON object per bag')


def evaluate_bag(bag: str, config: str | None) -> dict[str, Any]:
    """Run the graph on ``bag`` and measure it against its gt.json."""
    from absscale_ros import graph
    from absscale_ros.sim import groundtruth
    gt = groundtruth.load(f'{bag}.gt.json')
    seen: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix='bench_scale_') as tmp:
        report = graph.run_graph(bag, config or _scene_config(gt, Path(tmp)),
                                 graph.RunOptions(mode='step'),
                                 inspect=lambda nodes: seen.update(_cloud_observations(nodes)))
    return measure(bag, report, _deserialized(report.pop('_latest')), gt,
                   observations=seen.get('observations'))


def _cloud_observations(nodes: dict[str, Any]) -> dict[str, Any]:
    """The published landmarks' observations from the sfm node's map ({} without a map)."""
    from absscale_ros.core import sfm_outputs
    session = getattr(nodes.get('sfm'), 'session', None)
    if session is None or session.engine is None:
        return {}
    engine = session.engine
    return {'observations': sfm_outputs.cloud_observations(
        sfm_outputs.best_segment(engine).map, engine.K, session.cfg.cloud_cfg)}


def _scene_config(gt: dict[str, Any], folder: Path) -> str:
    """
    The scene's config looking for the bag's own target, as its user would configure it (the
    indoor config looks for letter; a quarter of the indoor seeds hold an A4 page).
    """
    from absscale_ros import params
    path = params.find_config(str(gt['scene']['name']))
    target = gt['scene'].get('variant', {}).get('target')
    data = yaml.safe_load(path.read_text())
    section = data.get('vertex_detector', {}).get('ros__parameters')
    if not target or section is None or section.get('target') == target:
        return str(path)
    section['target'] = target
    out = folder / path.name
    out.write_text(yaml.safe_dump(data))
    return str(out)


def _deserialized(latest: dict[str, tuple[Any, bytes]]) -> dict[str, Any]:
    """A run's last messages by topic, from the (message class, CDR bytes) it kept."""
    from rclpy.serialization import deserialize_message
    return {t: deserialize_message(d, c) for t, (c, d) in latest.items()}


def against_truth_file(bag: str, report: dict[str, Any],
                       latest: dict[str, tuple[Any, bytes]]) -> dict[str, Any]:
    """
    Scale error of a finished run against ``BAG.gt.json`` when the bag is a simulator's
    ({} when there is no ground truth beside it).

    :param latest: the run's last (message class, CDR bytes) by topic.
    """
    gt_path = Path(f'{bag}.gt.json')
    if not gt_path.exists():
        return {}
    from absscale_ros.sim import groundtruth
    return measure(bag, report, _deserialized(latest), groundtruth.load(gt_path), lengths=False)


def measure(bag: str, report: dict[str, Any], msgs: dict[str, Any], gt: dict[str, Any],
            lengths: bool = True, observations: list[tuple[Any, Any]] | None = None
            ) -> dict[str, Any]:
    """
    Scale error and (with ``lengths``) Table 3 length errors of one finished run.

    :param msgs: the run's last messages by topic (deserialized).
    :param observations: per published landmark, the stamps and undistorted px that observed
        it (``sfm_outputs.cloud_observations``); without them only the projected truth.
    """
    from absscale_ros import conversions
    from absscale_ros.core import evaluation
    scene = str(gt['scene']['name'])
    scale_report = report['nodes'].get('scale', {})
    result: dict[str, Any] = {'bag': bag, 'scene': scene, 'observable':
                              bool(scale_report.get('observable')),
                              'reason': scale_report.get('reason', '')}
    if not result['observable'] or '/absscale/keyframe_path' not in msgs:
        return result
    frames = {int(f['stamp_ns']): i for i, f in enumerate(gt['frames'])}  # type: ignore
    poses, stamps = conversions.path_msg_to_poses(msgs['/absscale/keyframe_path'])
    idx = [frames[int(s)] for s in stamps]
    gt_centres = np.array([np.array(gt['frames'][i]['T_world_cam'])[:3, 3]  # type: ignore
                           for i in idx])
    factor, sigma = scale_report['factor'], scale_report['sigma']
    truth_factor = evaluation.true_scale(poses[:, :3], gt_centres)
    result.update(factor=factor, sigma=sigma, true_factor=truth_factor,
                  scale_error_mm_per_m=1000.0 * (factor / truth_factor - 1.0),
                  claimed_sigma_mm_per_m=1000.0 * sigma / factor)
    # The same against only the keyframes that see the target: where the two differ, the
    # reconstruction's own scale drifts away from the target (the paper's drift problem).
    near = [k for k, i in enumerate(idx)
            if any(t['covers_min_area'] for t in gt['frames'][i]['targets'])]
    if len(near) >= 3:
        local = evaluation.true_scale(poses[near, :3], gt_centres[near])
        result['local_scale_error_mm_per_m'] = 1000.0 * (factor / local - 1.0)
    if lengths and '/scaled_cloud' in msgs and '/absscale/scaled_path' in msgs:
        try:
            result.update(_lengths(gt, msgs, idx, observations))
        except ValueError as err:  # e.g. gt.json from another renderer version
            result['lengths_error'] = str(err)
    return result


def _lengths(gt: dict[str, Any], msgs: dict[str, Any], idx: list[int],
             observations: list[tuple[Any, Any]] | None) -> dict[str, Any]:
    """Table 3 figures of one run's metric landmarks (see ``core/evaluation.py``)."""
    from absscale_ros import conversions
    from absscale_ros.core import evaluation
    from absscale_ros.sim import groundtruth
    cloud = conversions.cloud_msg_to_array(msgs['/scaled_cloud'], skip_nans=True)
    pts = np.stack([cloud[a] for a in 'xyz'], axis=1).astype(np.float64)
    metric_poses, _ = conversions.path_msg_to_poses(msgs['/absscale/scaled_path'])
    camera = groundtruth.camera_from_json(gt['camera'])  # type: ignore[arg-type]

    def behind(k: int, px: np.ndarray) -> np.ndarray:
        return groundtruth.points_behind_pixels(gt, k, px)
    projected = evaluation.landmark_truth(pts, metric_poses, idx, camera, behind)
    out = {'landmarks': len(pts), 'truth': 'projected',
           'landmarks_with_truth': int(np.isfinite(projected[:, 0]).sum()),
           'lengths': evaluation.length_errors(pts, projected, np.random.default_rng(0)).__dict__}
    if observations is None or len(observations) != len(pts):
        return out  # no map, or not the published cloud's landmarks
    frame_of = {int(f['stamp_ns']): k for k, f in enumerate(gt['frames'])}  # type: ignore
    try:
        seen = [(np.array([frame_of[int(s)] for s in stamps]), uv) for stamps, uv in observations]
    except KeyError as err:  # a keyframe the gt.json has no frame for: another bag's truth
        raise ValueError(f'keyframe stamp {err} is not in gt.json') from err
    truth = evaluation.observed_truth(seen, camera, behind)
    out.update(truth='observations', landmarks_with_truth=int(np.isfinite(truth[:, 0]).sum()),
               lengths=evaluation.length_errors(pts, truth, np.random.default_rng(0)).__dict__,
               lengths_projected=out['lengths'],
               landmarks_with_projected_truth=out['landmarks_with_truth'])
    out.update(_decomposition(gt, pts, truth, seen, camera.K))
    return out


def _decomposition(gt: dict[str, Any], pts: np.ndarray, truth: np.ndarray,
                   seen: list[tuple[np.ndarray, np.ndarray]], K: np.ndarray) -> dict[str, Any]:
    """
    Where the Table 3 error comes from: the cloud's own scale error (against its landmarks'
    truth, not the trajectory's), the lengths with it removed (the landmarks' shape alone),
    and the lengths of the same landmarks triangulated from the true poses (the observations
    alone, without the map's poses).
    """
    from absscale_ros.core import evaluation
    cloud_error = evaluation.cloud_scale_error(pts, truth)
    true_poses = np.array([f['T_world_cam'] for f in gt['frames']], np.float64)  # type: ignore
    retriangulated = evaluation.triangulate(seen, true_poses, K)
    return {'cloud_scale_error_mm_per_m': cloud_error,
            'lengths_cloud_scale': evaluation.length_errors(
                pts / (1.0 + cloud_error / 1000.0), truth, np.random.default_rng(0)).__dict__,
            'lengths_true_poses': evaluation.length_errors(
                retriangulated, truth, np.random.default_rng(0)).__dict__}


def run(args: argparse.Namespace) -> int:
    if not args.json:
        print(f'{"bag":<28} {"scale err mm/m":>14} {"near target":>11} {"claimed sigma":>13} '
              f'{"n":>5} {"mean":>6} {"max":>6} {"std":>6}', flush=True)
    for bag in args.bags:
        r = evaluate_bag(bag, args.config)
        if args.json:
            print(json.dumps(r), flush=True)
            continue
        if not r['observable']:
            print(f'{Path(r["bag"]).name:<28} no scale: {r["reason"]}')
            continue
        lengths = r.get('lengths', {'count': 0, 'mean': np.nan, 'max': np.nan, 'std': np.nan})
        print(f'{Path(r["bag"]).name:<28} {r["scale_error_mm_per_m"]:>14.2f} '
              f'{r.get("local_scale_error_mm_per_m", np.nan):>11.2f} '
              f'{r["claimed_sigma_mm_per_m"]:>13.2f} {lengths["count"]:>5} '
              f'{lengths["mean"]:>6.2f} {lengths["max"]:>6.2f} {lengths["std"]:>6.2f}',
              flush=True)
    if args.json:
        return 0
    for kind, (n, mean, mx, std) in PAPER_TABLE3.items():
        print(f'{"paper, " + kind:<28} {"":>14} {"":>11} {"":>13} {n:>5} {mean:>6.1f} {mx:>6.1f} '
              f'{std:>6.1f}')
    return 0
