"""
``absscale bench sfm BAG...``: incremental SfM accuracy and speed against simulator truth.

Keyframes are every ``--every``-th frame, or the keyframe selector's choice (``--select``, with
the ground-truth target areas), or exactly those the map of an ``absscale run`` was given
(``--keyframes-from report.json``: live, the keyframes it did not skip, so one command replays
a live run offline). Vertices are the ground-truth ``vertices_px`` of visible vertices plus
Gaussian noise (``--vertex-noise-px``), or the vertex detector's (``--detector``; then a
landmark is scored against the nearest true vertex). Sources are bags with ``BAG.gt.json``
beside them, or ``--sim SCENE:SEED`` rendered on the fly. Prints per bag: camera centre RMSE
after a Sim(3) (Umeyama) alignment of the centres as % of the trajectory length, and after the
pose alignment (``align.pose_similarity``: the rotation from the keyframes' orientations, which
a nearly straight path's centres leave loose about the path), reprojection RMS, vertex
landmarks and their 3D error after the pose alignment (and after the centres') as % of the
scene extent (all, and those the scale node would use), median and max update time per
keyframe (wall, and CPU: on a shared machine wall time overstates), segments;
optionally the same keyframes through pycolmap. ``--run DIR`` (one per BAG) instead scores
the scale factor of a finished ``absscale run`` against the truth.
"""
import argparse
import json
import time
from typing import Any, Iterator

import numpy as np

from absscale_ros import bagio, conversions
from absscale_ros.core import align, keyframes, sfm, sfm_outputs
from absscale_ros.core import vertex_matching as vm
from absscale_ros.core.types import CameraModel

Keyframe = tuple[int, np.ndarray, np.ndarray, dict[str, Any]]  # stamp, image, T_world_cam, truth


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('bags', nargs='*', metavar='BAG', help='bags with BAG.gt.json beside')
    parser.add_argument('--sim', action='append', default=[], metavar='SCENE:SEED',
                        help='render this simulator scene instead of reading a bag')
    parser.add_argument('--frames', type=int, default=300, help='frames of a --sim video')
    parser.add_argument('--width', type=int, default=1280, help='image width of a --sim video')
    parser.add_argument('--every', type=int, default=10, help='keyframe = every Nth frame')
    parser.add_argument('--select', action='store_true',
                        help='keyframes from the keyframe selector (ground-truth target areas)')
    parser.add_argument('--detector', action='store_true',
                        help='vertices from the vertex detector instead of ground truth + noise')
    parser.add_argument('--keyframes-from', metavar='REPORT',
                        help='keyframes: those the sfm map of an `absscale run` was given '
                             '(its report.json; live: those not skipped)')
    parser.add_argument('--run', action='append', default=[], metavar='DIR',
                        help='instead: scale error of the `absscale run` output DIR of each BAG')
    parser.add_argument('--vertex-noise-px', type=float, default=0.3)
    parser.add_argument('--seed', type=int, default=0, help='seed of noise and RANSAC')
    parser.add_argument('--colmap', action='store_true', help='also run pycolmap on the keyframes')
    parser.add_argument('--json', action='store_true', help='print the figures as JSON')
    parser.add_argument('--config', default=None,
                        help="take the sfm settings from this config's sfm section (a name or a "
                             'YAML path; default: the core defaults)')


def run_keyframe_stamps(report_path: str) -> list[int]:
    """
    The keyframes an ``absscale run``'s map was given (report.json ``nodes.sfm``; live, those
    it did not skip), or, in a report from before the sfm node listed them, those the
    keyframe selector chose.
    """
    with open(report_path) as f:
        nodes = json.load(f)['nodes']
    stamps = nodes.get('sfm', {}).get('keyframe_stamps_ns')
    return stamps if stamps is not None else nodes['keyframe_selector']['keyframe_stamps_ns']


def run_keyframe_steps(report_path: str) -> dict[int, keyframes.TrackedStep]:
    """
    The tracked step each keyframe of an ``absscale run``'s map came with, by stamp (none in
    reports from before the sfm node listed them): a replay then checks its poses against the
    same motion, which is what keeps aliased poses out of a live map.
    """
    with open(report_path) as f:
        sfm_report = json.load(f)['nodes'].get('sfm', {})
    pairs = zip(sfm_report.get('keyframe_stamps_ns', []), sfm_report.get('keyframe_steps', []))
    return {stamp: keyframes.TrackedStep(
        int(step['ref_stamp_ns']), np.reshape(np.array(step['rotation'], float), (3, 3)),
        np.array(step['centre'], float)) for stamp, step in pairs if step is not None}


def _keyframe_indices(path: str, gt: dict[str, Any], args: argparse.Namespace) -> set[int]:
    if getattr(args, 'keyframes_from', None):
        stamps = set(run_keyframe_stamps(args.keyframes_from))
        return {k for k, fr in enumerate(gt['frames']) if fr['stamp_ns'] in stamps}
    if not args.select:
        return set(range(0, len(gt['frames']), args.every))
    from absscale_ros.tools import bench_keyframes
    decisions, _ = bench_keyframes.select(path, keyframes.KeyframeConfig(),
                                          bench_keyframes.gt_areas(gt))
    stamps = {d.stamp_ns for d in decisions if d.keyframe}
    return {k for k, fr in enumerate(gt['frames']) if fr['stamp_ns'] in stamps}


def _from_bag(path: str, args: argparse.Namespace) -> tuple[CameraModel, dict[str, Any],
                                                            Iterator[Keyframe]]:
    with open(path + '.gt.json') as f:
        gt = json.load(f)
    cam = gt['camera']
    camera = CameraModel(cam['width'], cam['height'], np.array(cam['K'], float),
                         np.array(cam['D'], float), cam['distortion_model'])
    chosen = _keyframe_indices(path, gt, args)

    def frames() -> Iterator[Keyframe]:
        with bagio.open_bag(path) as reader:
            for k, msg in enumerate(reader.messages([gt['bag']['image_topic']])):
                if k not in chosen:
                    continue
                m = reader.deserialize(msg)
                img = (conversions.compressed_msg_to_bgr(m) if 'Compressed' in msg.msgtype
                       else conversions.image_msg_to_bgr(m))
                fr = gt['frames'][k]
                yield fr['stamp_ns'], img, np.array(fr['T_world_cam']), fr
    return camera, gt, frames()


def _from_sim(spec: str, args: argparse.Namespace) -> tuple[CameraModel, dict[str, Any],
                                                            Iterator[Keyframe]]:
    from absscale_ros.sim import simulation
    scene, seed = spec.split(':')
    sim = simulation.Simulation(simulation.SimConfig(scene, int(seed), frames=args.frames,
                                                     width=args.width,
                                                     height=args.width * 9 // 16))
    gt = sim.header({})

    def frames() -> Iterator[Keyframe]:
        for fr in sim.frames():
            if fr.index % args.every == 0:
                yield fr.stamp_ns, fr.image_bgr, np.array(fr.truth['T_world_cam']), fr.truth
    return sim.camera, gt, frames()


def _vertices(truth: dict[str, Any], gt: dict[str, Any], rng: np.random.Generator,
              noise_px: float) -> tuple[vm.Vertices, list[tuple[int, int]]]:
    """Visible ground-truth vertices + noise, renumbered per frame; and their true ids."""
    obj, vid, px, kinds, true = [], [], [], [], []
    for tf in truth['targets']:
        kind = gt['targets'][tf['id']]['kind']
        vis = [i for i, ok in enumerate(tf['vertex_visible']) if ok]
        if kind == 'sheet':
            vis = list(np.roll(vis, int(rng.integers(4)))) if len(vis) == 4 else []
        else:
            vis = list(rng.permutation(vis))
        for n, i in enumerate(vis):
            obj.append(tf['id'])
            vid.append(n)
            px.append(np.array(tf['vertices_px'][i]) + rng.normal(0.0, noise_px, 2))
            kinds.append(kind)
            true.append((tf['id'], int(i)))
    return (vm.Vertices(np.array(obj, np.int64), np.array(vid, np.int64),
                        np.array(px, float).reshape(-1, 2), tuple(kinds)), true)


def _detected(image: np.ndarray, camera: CameraModel, gt: dict[str, Any]) -> vm.Vertices | None:
    """
    The vertex detector's vertices of one keyframe (target type from the ground truth: the
    scene's sheet size, as ``bench scale`` configures it; letter when the bag does not say).
    """
    from absscale_ros.core import detect
    cube = any(t['kind'] == 'cube' for t in gt['targets'])
    sheet = gt.get('scene', {}).get('variant', {}).get('target', 'letter')
    result = detect.detect(image, detect.DetectConfig(target='cube' if cube else sheet),
                           camera.K)
    return sfm_outputs.vertices_from_rows(detect.vertices_array(result))


def _config(args: argparse.Namespace) -> sfm.SfmConfig:
    """The SfM settings a run with ``--config`` would use (the sfm node's section)."""
    if getattr(args, 'config', None) is None:
        return sfm.SfmConfig()
    from absscale_ros import params
    sections = params.load_yaml(params.find_config(args.config))
    return sfm.config_from_params(params.node_params(sections, 'sfm'))


def bench_one(camera: CameraModel, gt: dict[str, Any], frames: Iterator[Keyframe],
              args: argparse.Namespace) -> dict[str, Any]:
    """Run the incremental SfM over the keyframes and score it."""
    rng = np.random.default_rng(args.seed)
    engine = sfm.IncrementalSfm(camera, _config(args), np.random.default_rng(args.seed))
    times_s, cpu_s, poses, truth, images, results = [], [], {}, {}, [], []
    steps = run_keyframe_steps(args.keyframes_from) \
        if getattr(args, 'keyframes_from', None) else {}
    for kf_id, (stamp, img, T, fr) in enumerate(frames):
        vertices, true_ids = (_detected(img, camera, gt), None) if args.detector else \
            _vertices(fr, gt, rng, args.vertex_noise_px)
        t0, c0 = time.perf_counter(), time.process_time()
        results.append(engine.add_keyframe(stamp, img, vertices, steps.get(stamp)))
        times_s.append(time.perf_counter() - t0)
        cpu_s.append(time.process_time() - c0)
        poses[kf_id], truth[kf_id] = T, true_ids
        if args.colmap:
            images.append(img)
    t0 = time.perf_counter()
    results.append(engine.finish())
    final_s = time.perf_counter() - t0
    out = score(engine, poses, truth, gt)
    out['final_batch_s'] = final_s
    out.update(keyframes_in=len(times_s), sfm_time_s=float(np.sum(times_s)) + final_s,
               median_update_ms=1e3 * float(np.median(times_s)),
               max_update_ms=1e3 * float(np.max(times_s)),
               median_update_cpu_ms=1e3 * float(np.median(cpu_s)),
               last_message=results[-2].message,
               statuses={s: sum(r.status == s for r in results) for s in
                         {r.status for r in results}})
    if args.colmap:
        from absscale_ros.tools import colmap_compare
        out['colmap'] = colmap_compare.run(camera, images, poses)
    return out


def score(engine: sfm.IncrementalSfm, poses: dict[int, np.ndarray],
          truth: dict[int, Any], gt: dict[str, Any]) -> dict[str, Any]:
    """Figures of the largest segment against ground truth."""
    seg = max(engine.segments, key=lambda s: len(s.map.keyframes))
    m = seg.map
    all_c = np.array([poses[k][:3, 3] for k in sorted(poses)])
    length_m = float(np.sum(np.linalg.norm(np.diff(all_c, axis=0), axis=1)))
    verts = np.vstack([np.array(t['vertices_world_m']) for t in gt['targets']])
    extent_m = float(np.linalg.norm(np.ptp(np.vstack([all_c, verts]), axis=0)))
    out: dict[str, Any] = {'segments': len(engine.segments), 'registered': len(m.keyframes),
                           'landmarks': len(m.landmarks), 'trajectory_m': length_m,
                           'extent_m': extent_m,
                           'reprojection_rms_px': m.reprojection_rms_px(engine.K)}
    ids, T = m.poses()
    if len(ids) < 3:
        return out
    gt_c = np.array([poses[i][:3, 3] for i in ids])
    s, R, t = align.umeyama(T[:, :3, 3], gt_c)
    # Against the scored segment's own path: the whole run's would flatter a split map.
    seg_c = np.array([poses[k][:3, 3] for k in sorted(ids)])
    out['segment_m'] = float(np.sum(np.linalg.norm(np.diff(seg_c, axis=0), axis=1)))
    out['centre_rmse_m'] = align.rmse(align.apply(s, R, t, T[:, :3, 3]), gt_c)
    out['centre_rmse_pct'] = 100.0 * out['centre_rmse_m'] / max(out['segment_m'], 1e-12)
    # Vertices after the keyframes' pose alignment (centre figure alongside): the centres alone
    # leave the roll about a nearly straight path open, which swings vertices off the path.
    sim_pose = align.pose_similarity(T, np.array([poses[i] for i in ids]))
    out['centre_rmse_pose_pct'] = 100.0 * align.rmse(
        align.apply(*sim_pose, T[:, :3, 3]), gt_c) / max(out['segment_m'], 1e-12)
    # Scored: the vertices the sfm node publishes (``sfm_outputs.published_vertices``); those
    # it keeps unpublished (too little parallax) are counted and scored apart.
    published = sfm_outputs.published_vertices(m, engine.cfg.vertex_cfg.publish_min_angle_deg)
    points, true_pts, usable = _vertex_truth(m, truth, gt, published)
    out['vertices'] = len(points)
    out['vertices_unique'] = len({m.landmarks[i].label for i in published})
    out['vertices_usable'] = int(np.sum(usable))
    out.update(vertex_identities(m, truth))
    held = [i for i, lm in m.landmarks.items() if lm.label is not None and i not in published]
    out['vertices_unpublished'] = len(held)
    if held:
        q = align.apply(*sim_pose, np.array([m.landmarks[i].point_world for i in held]))
        out['vertex_err_unpublished_max_pct'] = 100.0 * float(max(
            np.min(np.linalg.norm(verts - x, axis=1)) for x in q)) / extent_m
    for suffix, sim in (('', sim_pose), ('_centres', (s, R, t))):
        if not points:
            break
        p = align.apply(*sim, np.array(points))
        errs = np.array([np.min(np.linalg.norm(verts - q, axis=1)) if tp is None else
                         np.linalg.norm(q - tp) for q, tp in zip(p, true_pts)])
        out[f'vertex_err_max{suffix}_pct'] = 100.0 * float(errs.max()) / extent_m
        out[f'vertex_err_median{suffix}_pct'] = 100.0 * float(np.median(errs)) / extent_m
        if np.any(usable):
            out[f'vertex_err_usable_max{suffix}_pct'] = \
                100.0 * float(errs[np.array(usable)].max()) / extent_m
    try:
        out.update(cloud_lengths(engine, m, (s, R, t), gt))
    except (ValueError, KeyError) as err:  # e.g. a gt.json of another renderer version
        out['lengths_error'] = str(err)
    return out


def _vertex_truth(m: Any, truth: dict[int, Any], gt: dict[str, Any], published: list[int]
                  ) -> tuple[list[np.ndarray], list[np.ndarray | None], list[bool]]:
    """
    Each published vertex landmark's position (SfM units), its true position (None for
    detected vertices: scored against the nearest true vertex) and whether the scale node would
    use it by default (>= 3 keyframes, >= 3 degrees of parallax).
    """
    points, true_pts, usable = [], [], []
    for lm_id in published:
        lm = m.landmarks[lm_id]
        usable.append(len(lm.obs_px) >= 3 and sfm_outputs.vertex_angle_deg(m, lm_id) >= 3.0)
        points.append(lm.point_world)
        kf = next(iter(lm.obs_px))
        if truth[kf] is None:
            true_pts.append(None)
            continue
        obj, vid = _corner(_true_ids(m, truth, lm_id))
        true_pts.append(np.array(gt['targets'][obj]['vertices_world_m'][vid]))
    return points, true_pts, usable


def _corner(ids: list[tuple[int, int]]) -> tuple[int, int]:
    """
    The true corner a landmark is scored against: that of most of its observations (fresh
    outdoor 45: a landmark 0.06 % from the corner of 44 of its 45 views was scored 3 % off
    against the corner of its first, a mismatch), the first on a tie.
    """
    return max(ids, key=ids.count)


def _true_ids(m: Any, truth: dict[int, Any], lm_id: int) -> list[tuple[int, int]]:
    """The true (object, vertex) of each observation of a vertex landmark."""
    return [tuple(truth[kf][int(np.flatnonzero(m.keyframes[kf].vertices.landmark_of == lm_id)[0])])
            for kf in m.landmarks[lm_id].obs_px]


def vertex_identities(m: Any, truth: dict[int, Any]) -> dict[str, int]:
    """
    With ground-truth vertices: landmarks whose observations are of more than one true corner
    (a mismatch), and landmarks beyond one per true corner (a corner that started a second
    landmark), each by the corner the error figures score it against (``_corner``); of every
    vertex landmark, published or not.
    """
    firsts, mixed = [], 0
    for lm_id, lm in m.landmarks.items():
        if lm.label is None or truth[next(iter(lm.obs_px))] is None:
            continue
        ids = _true_ids(m, truth, lm_id)
        firsts.append(_corner(ids))
        mixed += len(set(ids)) > 1
    return {'vertices_mixed': mixed, 'vertices_duplicate': len(firsts) - len(set(firsts))}


def cloud_lengths(engine: sfm.IncrementalSfm, m: Any, sim3: tuple[float, np.ndarray, np.ndarray],
                  gt: dict[str, Any]) -> dict[str, Any]:
    """
    The paper's Table 3 on the map after the camera-centre Sim(3): mean error of lengths
    between landmarks (mm/m) against the true surface behind them, for every landmark and for
    the published (well-triangulated) ones. The alignment's scale is the best possible, so this
    is the map's shape error, without the scale node's.
    """
    from scipy.spatial.transform import Rotation
    from absscale_ros.core import evaluation, landmark_quality
    from absscale_ros.sim import groundtruth
    frame_of = {int(f['stamp_ns']): k for k, f in enumerate(gt['frames'])}
    ids = sorted(m.keyframes)
    frames = [frame_of[m.keyframes[i].stamp_ns] for i in ids]
    T = np.array([gt['frames'][k]['T_world_cam'] for k in frames], float)
    poses = np.hstack([T[:, :3, 3], Rotation.from_matrix(T[:, :3, :3]).as_quat()])
    camera = groundtruth.camera_from_json(gt['camera'])
    out: dict[str, Any] = {}
    published = landmark_quality.well_triangulated(m, engine.K, engine.cfg.cloud_cfg)
    for name, lm_ids in (('all', list(m.landmarks)), ('published', published)):
        pts = align.apply(*sim3, np.array([m.landmarks[i].point_world for i in lm_ids]))
        truth = evaluation.landmark_truth(
            pts, poses, frames, camera, lambda k, px: groundtruth.points_behind_pixels(gt, k, px))
        st = evaluation.length_errors(pts, truth, np.random.default_rng(0))
        out[f'lengths_{name}'] = {'landmarks': len(pts), 'pairs': st.count,
                                  'mean_mm_per_m': st.mean, 'max_mm_per_m': st.max}
    return out


def _line(name: str, r: dict[str, Any]) -> str:
    def f(key: str, spec: str) -> str:
        return format(r[key], spec) if key in r else '-'
    return (f'{name:<22} kf {r["registered"]:>3}/{r["keyframes_in"]:<3} seg {r["segments"]} '
            f'rmse {f("centre_rmse_pct", ".3f")}% (pose-aligned '
            f'{f("centre_rmse_pose_pct", ".3f")}%) '
            f'reproj {f("reprojection_rms_px", ".2f")}px vtx {r.get("vertices", 0)} err med/max '
            f'{f("vertex_err_median_pct", ".3f")}/{f("vertex_err_max_pct", ".3f")}% (centre-'
            f'aligned {f("vertex_err_median_centres_pct", ".3f")}/'
            f'{f("vertex_err_max_centres_pct", ".3f")}%) usable {r.get("vertices_usable", 0)} max '
            f'{f("vertex_err_usable_max_pct", ".3f")}% upd med/max {f("median_update_ms", ".0f")}/'
            f'{f("max_update_ms", ".0f")}ms cpu med {f("median_update_cpu_ms", ".0f")}ms')


def scale_error(bag: str, run_dir: str) -> dict[str, Any]:
    """
    The scale node's factor of an ``absscale run`` against the truth: the Umeyama scale that
    maps the run's keyframe centres onto the true ones; error in mm per metre.
    """
    from pathlib import Path
    from absscale_ros.core import cloud
    report = json.loads((Path(run_dir) / 'report.json').read_text())
    sc = report['nodes'].get('scale', {})
    out: dict[str, Any] = {'factor': sc.get('factor'), 'reason': sc.get('reason', '')}
    tum = Path(run_dir) / 'trajectory.tum'
    if sc.get('factor') is None or not tum.exists():
        return out
    with open(bag + '.gt.json') as f:
        truth = {fr['stamp_ns']: np.array(fr['T_world_cam']) for fr in json.load(f)['frames']}
    stamps, poses = cloud.read_tum(tum)
    keep = [i for i, st in enumerate(stamps) if int(st) in truth]
    gt_c = np.array([truth[int(stamps[i])][:3, 3] for i in keep])
    s, _, _ = align.umeyama(poses[keep, :3], gt_c)
    metric = report.get('outputs', {}).get('trajectory.tum', {}).get('units') == 'metres' or \
        (Path(run_dir) / 'scaled_cloud.ply').exists()
    true_factor = s * sc['factor'] if metric else s  # trajectory.tum is metric once scaled
    out.update(true_factor=true_factor, keyframes=len(keep),
               error_mm_per_m=1e3 * (sc['factor'] / true_factor - 1.0))
    return out


def run(args: argparse.Namespace) -> int:
    if args.run:
        for bag, run_dir in zip(args.bags, args.run, strict=True):
            e = scale_error(bag, run_dir)
            print(f'{bag}: ' + (f'factor {e["factor"]:.6g} m/unit, true {e["true_factor"]:.6g}, '
                                f'error {e["error_mm_per_m"]:+.2f} mm/m over {e["keyframes"]} '
                                f'keyframes' if 'true_factor' in e else
                                f'no scale ({e["reason"]})'))
        return 0
    sources = [(b, lambda b=b: _from_bag(b, args)) for b in args.bags]
    sources += [(s, lambda s=s: _from_sim(s, args)) for s in args.sim]
    if not sources:
        print('absscale bench sfm: give BAG... or --sim SCENE:SEED')
        return 2
    report = {}
    for name, make in sources:
        camera, gt, frames = make()
        report[name] = r = bench_one(camera, gt, frames, args)
        if not args.json:
            print(_line(name, r))
            print(f'{"":<22} {r["last_message"]}')
            if 'colmap' in r:
                print(f'{"":<22} {colmap_line(r)}')
    if args.json:
        print(json.dumps(report, indent=1))
    return 0


def colmap_line(r: dict[str, Any]) -> str:
    c = r['colmap']
    if 'error' in c:
        return f'pycolmap: {c["error"]}'
    ratio_t = r['sfm_time_s'] / max(c['time_s'], 1e-9)
    ratio_e = r.get('centre_rmse_m', float('nan')) / max(c.get('centre_rmse_m', float('nan')),
                                                         1e-12)
    return (f'pycolmap: {c["registered"]} kf, rmse {c.get("centre_rmse_pct", float("nan")):.3f}%'
            f', {c["time_s"]:.1f}s vs ours {r["sfm_time_s"]:.1f}s; time ratio ours/colmap '
            f'{ratio_t:.2f}, rmse ratio ours/colmap {ratio_e:.2f}')
