"""
Incremental SfM on rendered simulator keyframes (not yet from bags: keyframes are every rendered
view of a short orbit, see ``sfm_scenes``), scored after a Sim(3) alignment to ground truth.
"""
from dataclasses import replace
from pathlib import Path
import sys

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from absscale_ros.core import aliasing, align, errors, keyframes, sfm, sfm_graph, sfm_vertices
from absscale_ros.core import twoview
from absscale_ros.core import features as feat

sys.path.insert(0, str(Path(__file__).parent))
import sfm_scenes  # noqa: E402


def _run(seq: sfm_scenes.Sequence, cfg: sfm.SfmConfig | None = None
         ) -> tuple[sfm.IncrementalSfm, list[sfm.UpdateResult]]:
    engine = sfm.IncrementalSfm(seq.camera, cfg or sfm.SfmConfig(), np.random.default_rng(7))
    return engine, [engine.add_keyframe(k, img) for k, img in enumerate(seq.images_bgr)]


@pytest.mark.parametrize('scene, seed', [('outdoor_cube', 1), ('indoor_paper', 0)])
def test_keyframe_centres_and_reprojection(scene: str, seed: int) -> None:
    seq = sfm_scenes.make_sequence(scene, seed, count=10)
    engine, results = _run(seq)
    assert results[-1].segments == 1 and results[-1].keyframes == 10
    ids, T = engine.current.map.poses()
    gt = seq.T_world_cams[ids, :3, 3]
    s, R, t = align.umeyama(T[:, :3, 3], gt)
    length_m = float(np.sum(np.linalg.norm(np.diff(seq.T_world_cams[:, :3, 3], axis=0), axis=1)))
    rmse_m = align.rmse(align.apply(s, R, t, T[:, :3, 3]), gt)
    assert rmse_m <= 0.003 * length_m  # issue 6: <= 0.3 % of the trajectory length
    assert results[-1].reprojection_rms_px <= 1.0


def test_two_view_landmarks_wait_outside_isam2() -> None:
    # Strictly three views into iSAM2 and no periodic batch: the two-view landmarks left out
    # are re-triangulated on the moved poses, so every update stays consistent and accurate.
    seq = sfm_scenes.make_sequence('outdoor_cube', 1, count=10)
    cfg = replace(sfm.SfmConfig(), graph_cfg=replace(sfm_graph.GraphConfig(), batch_every=100,
                                                     incremental_min_obs=0))
    engine = sfm.IncrementalSfm(seq.camera, cfg, np.random.default_rng(7))
    results = [engine.add_keyframe(k, img) for k, img in enumerate(seq.images_bgr)]
    m = engine.current.map
    assert results[-1].keyframes == 10 and results[-1].segments == 1
    assert max(r.reprojection_rms_px for r in results[1:]) <= 1.0
    assert m.reprojection_rms_px(engine.K) <= 1.0
    observations = sum(len(lm.obs_px) for lm in m.landmarks.values())
    assert engine.current.graph.observations_in < 0.8 * observations
    ids, T = m.poses()
    gt = seq.T_world_cams[ids, :3, 3]
    s, R, t = align.umeyama(T[:, :3, 3], gt)
    length_m = float(np.sum(np.linalg.norm(np.diff(gt, axis=0), axis=1)))
    assert align.rmse(align.apply(s, R, t, T[:, :3, 3]), gt) <= 0.003 * length_m


def test_windowed_smoother_on_a_longer_orbit() -> None:
    # iSAM2 holds all but the newest 3 keyframes fixed between batches (restarted every 3);
    # the map must stay as accurate as the issue asks, the final batch included.
    seq = sfm_scenes.make_sequence('indoor_paper', 3, count=12, arc_deg=50.0)
    # A short matching reach: descriptors of keyframes beyond it are dropped (memory).
    cfg = replace(sfm.SfmConfig(), graph_cfg=replace(sfm_graph.GraphConfig(), window=3,
                                                     batch_every=10),
                  relocalise_window=4, max_pending=2,
                  local_cfg=replace(sfm.SfmConfig().local_cfg, keyframes=4))
    engine = sfm.IncrementalSfm(seq.camera, cfg, np.random.default_rng(7))
    held = []
    for k, img in enumerate(seq.images_bgr):
        engine.add_keyframe(k, img)
        held.append(engine.current.graph.held_before)
    assert max(held) >= 6 and len(set(held)) >= 3  # restarted more than once
    result = engine.finish()
    ids, T = engine.current.map.poses()
    # The first two keyframes are 1.9-2 degrees apart: the initial pair is the first or second.
    assert result.keyframes >= 11 and result.reprojection_rms_px <= 1.0
    kept = [len(engine.current.map.keyframes[i].features.descriptors) > 0 for i in ids]
    assert kept == [False] * (len(ids) - 4) + [True] * 4  # the newest 4 can still be matched
    points = [len(engine.current.map.keyframes[i].features.points_px) > 0 for i in ids]
    assert points == kept  # and only they keep their keypoints
    gt = seq.T_world_cams[ids, :3, 3]
    s, R, t = align.umeyama(T[:, :3, 3], gt)
    length_m = float(np.sum(np.linalg.norm(np.diff(gt, axis=0), axis=1)))
    assert align.rmse(align.apply(s, R, t, T[:, :3, 3]), gt) <= 0.003 * length_m


def test_pure_rotation_never_initialises() -> None:
    seq = sfm_scenes.make_sequence('outdoor_cube', 2, count=5, arc_deg=30.0, rotate_only=True)
    _, results = _run(seq)
    assert all(r.status == 'pending' and r.keyframes == 0 for r in results)
    assert 'rotation' in results[-1].message or 'parallax' in results[-1].message


def test_umeyama_recovers_a_similarity() -> None:
    rng = np.random.default_rng(3)
    src = rng.normal(size=(20, 3))
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                  [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                  [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    dst = 2.5 * src @ R.T + [1.0, -2.0, 0.5]
    s, R_hat, t_hat = align.umeyama(src, dst)
    assert s == pytest.approx(2.5, rel=1e-9)
    assert np.allclose(R_hat, R, atol=1e-9) and np.allclose(t_hat, [1.0, -2.0, 0.5], atol=1e-9)
    with pytest.raises(errors.DegenerateGeometryError):
        align.umeyama(src[:2], dst[:2])


def _extent_m(seq: sfm_scenes.Sequence) -> float:
    """Scene extent: bounding-box diagonal of the camera centres and the target's vertices."""
    pts = np.vstack([seq.T_world_cams[:, :3, 3], seq.vertices_world_m])
    return float(np.linalg.norm(pts.max(0) - pts.min(0)))


@pytest.mark.parametrize('scene, seed', [('indoor_paper', 1), ('outdoor_cube', 2)])
def test_vertex_landmarks_keep_ids_and_are_accurate(scene: str, seed: int) -> None:
    # "Detected" vertices are the ground-truth 2D vertices + 0.3 px noise, renumbered per frame
    # (the vertex detector is not wired yet); matching must recover the identities.
    seq = sfm_scenes.make_sequence(scene, seed, count=10)
    rng = np.random.default_rng(5)
    engine = sfm.IncrementalSfm(seq.camera, sfm.SfmConfig(), np.random.default_rng(7))
    truth = []
    for k, img in enumerate(seq.images_bgr):
        vertices, true_ids = sfm_scenes.detections(seq, k, rng)
        truth.append(true_ids)
        engine.add_keyframe(k, img, vertices)
    m = engine.current.map
    ids, T = m.poses()
    s, R, t = align.umeyama(T[:, :3, 3], seq.T_world_cams[ids, :3, 3])
    labelled = [(lm_id, lm) for lm_id, lm in m.landmarks.items() if lm.label is not None]
    assert len(labelled) >= 3
    errors_m = []
    for lm_id, lm in labelled:
        seen_as = {int(truth[kf][np.flatnonzero(m.keyframes[kf].vertices.landmark_of == lm_id)[0]])
                   for kf in lm.obs_px}
        assert len(seen_as) == 1  # every observation is the same physical vertex
        p = align.apply(s, R, t, lm.point_world[None])[0]
        errors_m.append(np.linalg.norm(p - seq.vertices_world_m[seen_as.pop()]))
    # Measured at 640 px, 10 keyframes on a 40 degree arc, 0.3 px vertex noise: median 0.05 %
    # (indoor) and 0.3-1.2 % (outdoor, 6 m away; it moves with every change to the renderer
    # or the features) of the scene extent. The outdoor error is one common offset (spread
    # < 0.1 %): the cameras' orientations are tilted 0.3-1 degree against the truth, a
    # bas-relief ambiguity of the short arc that an alignment fitted on camera centres cannot
    # remove. So this bounds gross errors only; the 0.1 % is measured on longer bags.
    assert np.median(errors_m) <= 0.02 * _extent_m(seq)
    assert max(errors_m) <= 0.03 * _extent_m(seq)
    # The shape the scale is taken from is much better than the offset: pairwise distances.
    P = align.apply(s, R, t, np.array([lm.point_world for _, lm in labelled]))
    true_ids = [int(truth[next(iter(lm.obs_px))][np.flatnonzero(
        m.keyframes[next(iter(lm.obs_px))].vertices.landmark_of == lm_id)[0]])
        for lm_id, lm in labelled]
    iu = np.triu_indices(len(P), 1)
    got = np.linalg.norm(P[:, None] - P[None], axis=2)[iu]
    want = np.linalg.norm(seq.vertices_world_m[true_ids][:, None]
                          - seq.vertices_world_m[true_ids][None], axis=2)[iu]
    assert np.median(np.abs(got / want - 1.0)) <= 0.01
    points, rows = sfm_vertices.targets(m)
    assert len(points) == len(labelled) and np.all(rows[:, 2] >= 2)


@pytest.fixture(scope='module')
def outdoor_orbit() -> sfm_scenes.Sequence:
    return sfm_scenes.make_sequence('outdoor_cube', 1, count=10)


# The two tests below sit near their thresholds on this orbit, whose map moves with the match
# set: they fix the matching (and iSAM2's entry) they were written with, to test the checks.
_FIXED_MATCHING = replace(
    sfm.SfmConfig(), feature_cfg=replace(feat.FeatureConfig(), flann_checks=32, flann_trees=4),
    graph_cfg=replace(sfm_graph.GraphConfig(), incremental_min_views=3))


def test_second_rigid_motion_makes_an_initial_pair_ambiguous(outdoor_orbit) -> None:
    # A repeated texture matched one period off is a second rigid motion among the matches;
    # here it is a real one: keyframe 2's matches with keyframe 8 mixed into those with 5.
    # The pair is weak (median ray angle ~2 degrees): its direction depends on the exact match
    # set (exact matching: too little parallax; FLANN 2 x 24: reversed), so the matching is
    # fixed here (4 trees, 32 leaves: 0.986 to the true direction; 2 x 16 gives 0.953).
    seq, cfg = outdoor_orbit, _FIXED_MATCHING
    engine = sfm.IncrementalSfm(seq.camera, cfg, np.random.default_rng(7))
    f = [feat.detect(seq.images_bgr[k], seq.camera, cfg.feature_cfg) for k in (2, 5, 8)]
    ab, ac = engine._verified(f[0], f[1]), engine._verified(f[0], f[2])
    n = min(len(ab), len(ac)) // 2
    pa, pb = f[0].points_px[ab[:, 0]], f[1].points_px[ab[:, 1]]
    T_b, _, ok = twoview.initialise(seq.camera.K, pa, pb, cfg.twoview_cfg,
                                    np.random.default_rng(0))
    true_rel = np.linalg.inv(seq.T_world_cams[2]) @ seq.T_world_cams[5]
    cos = T_b[:3, 3] @ true_rel[:3, 3] / np.linalg.norm(true_rel[:3, 3])
    assert cos > 0.97 and ok.sum() >= cfg.twoview_cfg.init_min_points  # one motion: fine
    mixed_a = np.vstack([pa[:2 * n], f[0].points_px[ac[:n, 0]]])
    mixed_b = np.vstack([pb[:2 * n], f[2].points_px[ac[:n, 1]]])
    with pytest.raises(errors.DegenerateGeometryError, match='ambiguous'):
        twoview.initialise(seq.camera.K, mixed_a, mixed_b, cfg.twoview_cfg,
                           np.random.default_rng(0))


def test_pose_off_by_a_texture_period_is_disowned(outdoor_orbit) -> None:
    # The map of the orbit; the newest keyframe's ground landmarks moved a "period" along the
    # ground (what matching one period off amounts to) carry a pose the rest of the scene
    # (cube, objects, facades) does not support. Near the threshold: the shifted pose's
    # off-plane support is 0.28-0.40 of the on-plane one (refused below 0.35) as the matching
    # and iSAM2 settings vary (0.34 with these).
    seq = outdoor_orbit
    engine, results = _run(seq, _FIXED_MATCHING)
    assert results[-1].segments == 1 and results[-1].keyframes == 10  # nothing refused
    m, kf = engine.current.map, engine.current.map.keyframes[9]
    kps = np.flatnonzero(kf.landmark_of >= 0)
    obj = np.array([m.landmarks[int(i)].point_world for i in kf.landmark_of[kps]])
    img = kf.features.points_px[kps]
    spread = float(np.median(np.linalg.norm(obj - np.median(obj, axis=0), axis=1)))
    rng = np.random.default_rng(0)
    on = aliasing.dominant_plane(obj, 0.02 * spread, rng)
    assert on.sum() > 0.5 * len(obj) and (~on).sum() >= 20
    normal = np.linalg.svd(obj[on] - obj[on].mean(0))[2][2]
    shifted = obj.copy()
    shifted[on] += 0.5 * spread * np.cross(normal, [1.0, 0.0, 0.0])  # in the plane
    reasons = []
    for points, fit in ((obj, np.ones(len(obj), bool)), (shifted, on)):
        _, rvec, tvec = cv2.solvePnP(points[fit], img[fit], seq.camera.K, None)
        err = np.linalg.norm(cv2.projectPoints(points, rvec, tvec, seq.camera.K, None)[0][:, 0]
                             - img, axis=1)
        reasons.append(aliasing.off_plane_reason(points, np.flatnonzero(err < 8.0), 0.02, 20,
                                                 0.35, rng))
    assert reasons[0] is None
    assert reasons[1] is not None and 'repeated texture' in reasons[1]


def test_velocity_reversal_is_implausible(outdoor_orbit) -> None:
    centres = outdoor_orbit.T_world_cams[:3, :3, 3]
    stamps = np.array([0, 100_000_000, 200_000_000], np.int64)
    assert aliasing.velocity_change(centres, stamps) < 1.0  # the orbit, hand shake and all
    assert aliasing.velocity_reason(centres, stamps, 1.2, 1.0) is None
    jumped = centres.copy()
    jumped[2] = centres[1] - 2.0 * (centres[2] - centres[1])  # one period back, not a step on
    assert aliasing.velocity_change(jumped, stamps) > 1.2
    assert 'repeated texture' in aliasing.velocity_reason(jumped, stamps, 1.2, 1.0)
    assert aliasing.velocity_reason(jumped, 10 * stamps, 1.2, 1.0) is None  # 2 s: may turn back


def test_a_camera_standing_still_keeps_registering(outdoor_orbit) -> None:
    # Keyframes of a still camera (the same view, new sensor noise) move by pose noise only,
    # which reverses the velocity at random: it is not an aliased jump (this refused keyframes
    # and broke the 60 s bag's segments at its standstills).
    seq, rng = outdoor_orbit, np.random.default_rng(0)
    engine = sfm.IncrementalSfm(seq.camera, sfm.SfmConfig(), np.random.default_rng(7))
    order = [0, 1, 2, 3, 4, 5, 5, 5, 5, 6, 7, 8, 9]
    results = []
    for n, k in enumerate(order):
        img = seq.images_bgr[k]
        if n and order[n - 1] == k:
            img = np.clip(img + rng.normal(0.0, 2.0, img.shape), 0, 255).astype(np.uint8)
        results.append(engine.add_keyframe(n * 100_000_000, img))
    assert [r.status for r in results[2:]] == ['registered'] * (len(order) - 2)
    assert results[-1].segments == 1 and results[-1].keyframes == len(order)


def test_pose_against_the_tracked_step_is_refused(outdoor_orbit) -> None:
    # The selector's tracked steps (here the true ones) let every true pose through; a step
    # tracked the opposite way of the pose PnP finds refuses it (what an aliased pose is).
    seq = outdoor_orbit

    def tracked(a: int, b: int, sign: float = 1.0) -> keyframes.TrackedStep:
        rel = np.linalg.inv(seq.T_world_cams[a]) @ seq.T_world_cams[b]
        return keyframes.TrackedStep(a, rel[:3, :3].T, sign * rel[:3, 3])
    # No relocalisation: the older keyframes' pavers would offer a pose a period away (it
    # agrees with the reversed step; the right step refuses it the same way).
    cfg = replace(sfm.SfmConfig(), relocalise_window=3)
    engine = sfm.IncrementalSfm(seq.camera, cfg, np.random.default_rng(7))
    results = [engine.add_keyframe(k, img, None, tracked(k - 1, k) if k else None)
               for k, img in enumerate(seq.images_bgr[:9])]
    assert results[-1].segments == 1 and results[-1].keyframes == 9
    last = engine.add_keyframe(9, seq.images_bgr[9], None, tracked(8, 9, -1.0))
    assert last.status == 'rejected' and 'tracked motion' in last.message
    T = seq.T_world_cams
    assert aliasing.step_angle_deg(T[8], T[9], (np.linalg.inv(T[8]) @ T[9])[:3, 3]) < 1e-6


def test_pose_similarity_fixes_the_roll_that_a_straight_path_leaves_open() -> None:
    # Cameras on a nearly straight line (1 mm off it) looking sideways: their centres, noisy by
    # 2 mm, fix the rotation about the line poorly; their orientations fix it well.
    rng = np.random.default_rng(4)
    R_true = Rotation.from_rotvec([0.3, -0.2, 0.9]).as_matrix()
    T_src = np.tile(np.eye(4), (20, 1, 1))
    T_src[:, :3, 3] = np.c_[np.linspace(0.0, 6.0, 20), rng.normal(0.0, 1e-3, (20, 2))]
    T_src[:, :3, :3] = Rotation.from_rotvec(rng.normal(0.0, 0.05, (20, 3))).as_matrix()
    T_dst = T_src.copy()
    T_dst[:, :3, :3] = R_true @ T_src[:, :3, :3]
    T_dst[:, :3, 3] = 2.0 * T_src[:, :3, 3] @ R_true.T + [1.0, 2.0, 3.0]
    s, R, t = align.pose_similarity(T_src, T_dst)  # exact poses: exact similarity
    assert s == pytest.approx(2.0, rel=1e-9)
    assert np.allclose(R, R_true, atol=1e-9) and np.allclose(t, [1.0, 2.0, 3.0], atol=1e-9)
    T_dst[:, :3, 3] += rng.normal(0.0, 2e-3, (20, 3))
    roll_err = [np.degrees(Rotation.from_matrix(fit(T_src, T_dst)[1] @ R_true.T).magnitude())
                for fit in (lambda a, b: align.umeyama(a[:, :3, 3], b[:, :3, 3]),
                            align.pose_similarity)]
    assert roll_err[1] < 1e-6 < 0.1 < roll_err[0]
    with pytest.raises(errors.DegenerateGeometryError):
        align.pose_similarity(T_src[:2], T_dst[:2])


def test_velocity_change_of_epoch_stamps_a_nanosecond_apart(outdoor_orbit) -> None:
    # float64 holds an epoch stamp in ns only to ~256 ns: the steps are taken in int64.
    centres = outdoor_orbit.T_world_cams[:3, :3, 3]
    near = aliasing.velocity_change(centres, np.array([0, 1, 2], np.int64))
    epoch = aliasing.velocity_change(centres, 10**18 + np.array([0, 1, 2], np.int64))
    assert np.isfinite(epoch) and epoch == pytest.approx(near)
