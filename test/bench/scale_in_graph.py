"""
Fitted factor against known-length factors in the graph (issue #7, deliverable 2).

``python test/bench/scale_in_graph.py BAG... [--config indoor_paper|outdoor_cube]``: the core
SfM runs over the bag's keyframes (the core selector) with the detector's vertices, then the
scale comes out two ways from the same map: ``scale.estimate`` (zero-intercept least squares over
the target's edges and diagonals) and ``metric_ba.adjust`` (those lengths as RangeFactor3 inside
a batch adjustment). Each is compared with the factor that best aligns the map's camera centres
with the ground truth; errors in mm per metre.
"""
import argparse
from dataclasses import fields
import json
import sys
import time

from absscale_ros import params
from absscale_ros.core import errors, evaluation, metric_ba, scale, sfm, sfm_outputs, targets
from absscale_ros.tools import bench_sfm
import numpy as np


def _scale_config(config: str) -> tuple[scale.ScaleConfig, dict]:
    p = params.node_params(params.load_yaml(params.find_config(config)), 'scale')
    names = {f.name for f in fields(scale.ScaleConfig)}
    return scale.ScaleConfig(**{k: v for k, v in p.items() if k in names}), p


def _objects(m, p: dict) -> tuple[list[scale.ObjectVertices], list[list[int]]]:
    tp = sfm_outputs.target_points(m)
    rows = sorted((lm.label, lm_id) for lm_id, lm in m.landmarks.items() if lm.label is not None)
    lm_ids = np.array([r[1] for r in rows])
    custom = tuple(p['sheet_size_m']) if min(p['sheet_size_m']) > 0 else None
    sizes = targets.sheet_sizes_m(p['sheet'], custom)
    objs = scale.group_objects(tp.points, tp.object_ids, tp.target_types, tp.n_obs,
                               tp.angle_deg, sizes[0], p['cube_edge_m'], tuple(sizes[1:]))
    return objs, [list(lm_ids[tp.object_ids == o.object_id]) for o in objs]


def one(bag: str, config: str | None, gt_vertices: bool, keyframes_from: str | None) -> dict:
    args = argparse.Namespace(keyframes_from=keyframes_from, select=True, every=10)
    camera, gt, frames = bench_sfm._from_bag(bag, args)
    cfg, p = _scale_config(config or gt['scene']['name'])
    engine = sfm.IncrementalSfm(camera, sfm.SfmConfig(), np.random.default_rng(0))
    rng = np.random.default_rng(0)
    for stamp, img, _, truth in frames:
        # Ground-truth vertices (+0.3 px noise) compare the two scale methods apart from
        # detection; the detector's are what a run sees.
        vertices = bench_sfm._vertices(truth, gt, rng, 0.3)[0] if gt_vertices else \
            bench_sfm._detected(img, camera, gt)
        engine.add_keyframe(stamp, img, vertices)
    engine.finish()
    m = sfm_outputs.best_segment(engine).map
    by_stamp = {f['stamp_ns']: np.array(f['T_world_cam'])[:3, 3] for f in gt['frames']}
    kf = sorted(m.keyframes)
    truth = evaluation.true_scale(np.array([m.keyframes[k].T_world_cam[:3, 3] for k in kf]),
                                  np.array([by_stamp[m.keyframes[k].stamp_ns] for k in kf]))
    out = {'bag': bag, 'keyframes': len(kf), 'true_factor': truth}
    objs, ids = _objects(m, p)
    try:
        est = scale.estimate(objs, cfg, len(kf))
    except errors.NotObservableError as err:
        return {**out, 'fitted': f'no scale: {err}'}
    known = []
    for obj, lm_ids in zip(objs, ids):
        try:
            known += metric_ba.constraints(m, obj, lm_ids, cfg)
        except errors.NotObservableError:
            pass
    t0 = time.process_time()
    graph_factor, _ = metric_ba.adjust(m, engine.K, known, est.factor,
                                       metric_ba.LengthFactorConfig())
    return {**out, 'lengths': len(known), 'graph_cpu_s': time.process_time() - t0,
            'fitted_mm_per_m': 1e3 * (est.factor / truth - 1.0),
            'fitted_sigma_mm_per_m': 1e3 * est.sigma / est.factor,
            'graph_mm_per_m': 1e3 * (graph_factor / truth - 1.0)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('bags', nargs='+')
    parser.add_argument('--config', default=None)
    parser.add_argument('--gt-vertices', action='store_true',
                        help='true vertices + 0.3 px noise instead of the detector')
    parser.add_argument('--keyframes-from', metavar='REPORT', action='append', default=[],
                        help="an 'absscale run' report.json per bag: use its keyframes")
    args = parser.parse_args(argv)
    for i, bag in enumerate(args.bags):
        report = args.keyframes_from[i] if i < len(args.keyframes_from) else None
        print(json.dumps(one(bag, args.config, args.gt_vertices, report), default=float),
              flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
