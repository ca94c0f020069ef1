"""Ground-truth side of ``absscale bench dense``: runs, keyframe poses, surface samples."""
from dataclasses import asdict
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from absscale_ros import bagio, conversions, params

FloatArray = np.ndarray
# Completeness radius per scene (issue 9).
RADIUS_M = {'indoor_paper': 0.02, 'outdoor_cube': 0.05}


def dense_configs(config: str) -> tuple[Any, Any, Any, Any, Any, Any]:
    """StereoConfig, FusionConfig, SweepConfig, FacadeConfig, FillConfig and GroundConfig of a
    config's ``dense``."""
    from dataclasses import fields
    from absscale_ros.core import dense_facade, dense_fill, dense_fusion, dense_ground, \
        dense_stereo, dense_sweep
    section = params.node_params(params.load_yaml(params.find_config(config)), 'dense')
    out = []
    for prefix, cls in (('stereo', dense_stereo.StereoConfig),
                        ('fusion', dense_fusion.FusionConfig),
                        ('sweep', dense_sweep.SweepConfig),
                        ('facade', dense_facade.FacadeConfig),
                        ('fill', dense_fill.FillConfig),
                        ('ground', dense_ground.GroundConfig)):
        names = {f.name for f in fields(cls)}
        out.append(cls(**{k.split('.', 1)[1]: v for k, v in section.items()
                          if k.startswith(prefix + '.') and k.split('.', 1)[1] in names}))
    return out[0], out[1], out[2], out[3], out[4], out[5]


def _keyframe_images(bag: str, stamps: set[int]) -> dict[int, np.ndarray]:
    images = {}
    with bagio.open_bag(bag) as reader:
        topic = next(t for t, i in reader.topics.items() if i.msgtype.endswith('Image'))
        for msg in reader.messages([topic]):
            ros = reader.deserialize(msg)
            stamp = conversions.stamp_to_ns(ros.header.stamp)
            if stamp in stamps:
                images[stamp] = conversions.compressed_msg_to_bgr(ros) \
                    if hasattr(ros, 'format') else conversions.image_msg_to_bgr(ros)
    return images


def core_on_true_poses(bag: str, gt: dict[str, Any], config: str) -> dict[str, Any]:
    """The dense core fed keyframe by keyframe with the true poses; CPU and wall time per
    update, with OpenCV on one thread as every node runs it (``common.one_opencv_thread``:
    its pool's spinning threads were counted as the update's CPU)."""
    import cv2
    before = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        return _core_on_true_poses(bag, gt, config)
    finally:
        cv2.setNumThreads(before)


def _core_on_true_poses(bag: str, gt: dict[str, Any], config: str) -> dict[str, Any]:
    from absscale_ros.core import dense_fusion
    from absscale_ros.sim import groundtruth
    from absscale_ros.tools import bench_keyframes
    decisions, _ = bench_keyframes.select(bag, bench_keyframes.config_from(config),
                                          bench_keyframes.gt_areas(gt))
    stamps = [d.stamp_ns for d in decisions if d.keyframe]
    images = _keyframe_images(bag, set(stamps))
    index = {int(f['stamp_ns']): k for k, f in enumerate(gt['frames'])}
    camera = groundtruth.camera_from_json(gt['camera'])
    fusion = dense_fusion.DenseFusion(*dense_configs(config))
    poses: dict[int, FloatArray] = {}
    times, walls = [], []
    for s in stamps:
        c0, t0 = time.process_time(), time.perf_counter()
        fusion.add_keyframe(s, images[s], camera)
        poses[s] = np.array(gt['frames'][index[s]]['T_world_cam'])
        fusion.update(poses)
        xyz, rgb, nrm = fusion.cloud()
        times.append(time.process_time() - c0)
        walls.append(time.perf_counter() - t0)
    return {'stamps': stamps, 'poses': poses, 'cloud': (xyz, rgb, nrm), 'times_s': times,
            'wall_s': walls, 'sparse_points': None, 'depth_computed': fusion.depth_computed}


def full_run(bag: str, config: str) -> dict[str, Any]:
    """The whole graph with the dense node on; its last dense cloud and metric poses."""
    import yaml
    from rclpy.serialization import deserialize_message
    from absscale_ros import graph
    data = yaml.safe_load(params.find_config(config).read_text())
    data.setdefault('dense', {}).setdefault('ros__parameters', {})['enabled'] = True
    with tempfile.NamedTemporaryFile('w', suffix='.yaml', delete=False) as f:
        yaml.safe_dump(data, f)
    try:
        report = graph.run_graph(bag, f.name, graph.RunOptions(mode='step'))
    finally:
        Path(f.name).unlink()
    msgs = {t: deserialize_message(d, c) for t, (c, d) in report.pop('_latest').items()}
    out: dict[str, Any] = {'stamps': [], 'poses': {}, 'times_s': [],
                           'report': report['nodes'].get('dense', {})}
    out['times_s'] = out['report'].get('update_s', [])
    out['wall_s'] = out['report'].get('update_wall_s', [])
    if '/absscale/scaled_path' not in msgs or '/scaled_cloud' not in msgs:
        return out
    poses, stamps = conversions.path_msg_to_poses(msgs['/absscale/scaled_path'])
    out['stamps'] = [int(s) for s in stamps]
    out['poses'] = {int(s): _matrix(p) for s, p in zip(stamps, poses)}
    out['cloud'] = conversions.cloud_msg_to_xyz_rgb_normals(msgs['/scaled_cloud'])
    sparse = msgs.get('/absscale/sparse_cloud_metric')
    out['sparse_points'] = None if sparse is None else sparse.width * sparse.height
    return out


def _matrix(pose_xyzw: FloatArray) -> FloatArray:
    from scipy.spatial.transform import Rotation
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(pose_xyzw[3:]).as_matrix()
    T[:3, 3] = pose_xyzw[:3]
    return T


def surface_samples(gt: dict[str, Any], frames: list[int], step: int,
                    mesh: Any) -> tuple[FloatArray, FloatArray]:
    """True surface points on a pixel grid of each keyframe that >= 2 keyframes see, and their
    depths in the keyframe they were sampled from."""
    from absscale_ros.sim import groundtruth
    camera = groundtruth.camera_from_json(gt['camera'])
    u, v = np.meshgrid(np.arange(step / 2, camera.width, step),
                       np.arange(step / 2, camera.height, step))
    px = np.stack([u.ravel(), v.ravel()], axis=1)
    poses = [np.array(gt['frames'][i]['T_world_cam']) for i in frames]
    pts, depths = [], []
    for i, T in zip(frames, poses):
        p = groundtruth.points_behind_pixels(gt, i, px)
        p = p[np.isfinite(p[:, 0])]
        pts.append(p)
        depths.append((p - T[:3, 3]) @ T[:3, 2])
    samples, depth = np.concatenate(pts), np.concatenate(depths)
    seen = sum(mesh.visible_from(samples, T, camera).astype(int) for T in poses)
    return samples[seen >= 2], depth[seen >= 2]


def evaluate_bag(bag: str, config: str | None, gt_poses: bool, sample_step: int,
                 ply: str | None, png: str | None = None) -> dict[str, Any]:
    """Every figure of ``absscale bench dense`` for one bag."""
    from absscale_ros.core import cloud, dense_evaluation
    from absscale_ros.sim import groundtruth
    gt = groundtruth.load(f'{bag}.gt.json')
    scene = str(gt['scene']['name'])
    config = config or scene
    run = core_on_true_poses(bag, gt, config) if gt_poses else full_run(bag, config)
    result: dict[str, Any] = {'bag': bag, 'scene': scene, 'mode': 'gt poses' if gt_poses
                              else 'full run'}
    if len(run['stamps']) < 3 or 'cloud' not in run:
        return {**result, 'error': 'no metric keyframe poses / dense cloud (no scale?)'}
    index = {int(f['stamp_ns']): k for k, f in enumerate(gt['frames'])}
    frames = [index[s] for s in run['stamps']]
    est = np.array([run['poses'][s][:3, 3] for s in run['stamps']])
    true = np.array([np.array(gt['frames'][i]['T_world_cam'])[:3, 3] for i in frames])
    R, t = dense_evaluation.rigid_alignment(est, true)
    xyz, rgb, normals = run['cloud']
    aligned = xyz @ R.T + t
    if ply:
        cloud.write_ply(Path(ply), aligned, rgb, normals @ R.T)
    if png:
        from absscale_ros import dense_figure
        dense_figure.draw(Path(png), aligned, rgb, normals @ R.T,
                          [np.array(gt['frames'][i]['T_world_cam']) for i in frames],
                          f'{Path(bag).name}: {len(xyz)} dense points, {result["mode"]}')
    renderer = groundtruth.renderer_for(gt)
    mesh = dense_evaluation.SceneMesh(renderer.scene.vertices_m, renderer.scene.triangles)
    samples, depths = surface_samples(gt, frames, sample_step, mesh)
    radius = RADIUS_M.get(scene, 0.05)
    s = dense_evaluation.score(aligned, mesh, samples, depths, radius)
    times, walls = np.array(run['times_s'], float), np.array(run.get('wall_s', []), float)
    sparse = run.get('sparse_points')
    return {**result, **asdict(s), 'median_rel': s.median_rel, 'p90_rel': s.p90_rel,
            'radius_m': radius, 'keyframes': len(frames), 'sparse_points': sparse,
            'sparse_ratio': s.points / sparse if sparse else float('nan'),
            'trajectory_rmse_m': float(np.sqrt(np.mean(np.sum((est @ R.T + t - true) ** 2, 1)))),
            'update_s_median': float(np.median(times)) if len(times) else None,
            'update_s_p95': float(np.percentile(times, 95)) if len(times) else None,
            'update_wall_s_median': float(np.median(walls)) if len(walls) else None,
            'update_wall_s_p95': float(np.percentile(walls, 95)) if len(walls) else None}
