"""Patch alignment of landmark observations on rendered frames (``core/landmark_refine.py``)."""
from pathlib import Path
import sys

import numpy as np
import pytest

from absscale_ros.core import features as feat
from absscale_ros.core import landmark_refine as lr
from absscale_ros.sim import render, scenes

sys.path.insert(0, str(Path(__file__).parent))
import sfm_scenes  # noqa: E402


@pytest.fixture(scope='module')
def pair():
    """Two 1280 px outdoor keyframes ~0.6 m apart, SIFT keypoints of the first with their
    true 3D points (ray cast) and true undistorted positions in the second."""
    seq = sfm_scenes.make_sequence('outdoor_cube', 3, count=2, width=1280, arc_deg=6.0)
    cam, K = seq.camera, seq.camera.K
    maps = lr.undistort_maps(cam)
    greys = [lr.undistorted_grey(im, maps) for im in seq.images_bgr]
    f = feat.detect(seq.images_bgr[0], cam, feat.FeatureConfig())
    T0, T1 = seq.T_world_cams
    rays = np.column_stack([(f.points_px - K[:2, 2]) / np.diag(K)[:2], np.ones(len(f.points_px))])
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    renderer = render.Renderer(scenes.build_scene('outdoor_cube', 3), cam)
    dist, _ = renderer.cast(T0, rays.astype(np.float32))
    dist = np.where(np.isfinite(dist), dist, 0.0).astype(np.float64)  # sky: dropped below
    X = T0[:3, 3] + (rays * dist[:, None]) @ T0[:3, :3].T
    p1 = (X - T1[:3, 3]) @ T1[:3, :3]
    uv1 = p1[:, :2] / p1[:, 2:] @ K[:2, :2].T + K[:2, 2]
    keep = (dist > 0.0) & (p1[:, 2] > 0) & np.all((uv1 > 40) & (uv1 < [cam.width - 40,
                                                                       cam.height - 40]), axis=1)
    return greys, seq.T_world_cams, K, f.points_px[keep], X[keep], uv1[keep]


def test_alignment_finds_the_true_correspondence(pair):
    greys, T, K, uv0, X, uv1 = pair
    assert len(uv0) > 200
    rng = np.random.default_rng(0)
    cfg = lr.RefineConfig()
    normals = lr.plane_normals(X, X, cfg.neighbours)
    # The landmark as triangulated: 1 cm off (its projection ~1-2 px off the truth).
    X_est = X + rng.normal(0.0, 0.01, X.shape)
    pred = (X_est - T[1, :3, 3]) @ T[1, :3, :3]
    pred_err = np.linalg.norm(pred[:, :2] / pred[:, 2:] @ K[:2, :2].T + K[:2, 2] - uv1, axis=1)
    found, ok = lr.align(greys[0], greys[1], T[0], T[1], K, X_est, normals, uv0, cfg)
    err = np.linalg.norm(found - uv1, axis=1)
    assert ok.mean() > 0.5
    # SIFT's own observations disagree by ~0.5 px (median) on such renders.
    assert np.median(err[ok]) < 0.3 < np.median(pred_err)
    assert np.percentile(err[ok], 90) < 1.0


def test_alignment_of_a_view_with_itself_is_exact(pair):
    greys, T, K, uv0, X, _ = pair
    cfg = lr.RefineConfig()
    found, ok = lr.align(greys[0], greys[0], T[0], T[0], K, X[:50],
                         lr.plane_normals(X[:50], X, cfg.neighbours), uv0[:50], cfg)
    assert ok.mean() > 0.8  # LK refuses the flattest patches
    np.testing.assert_allclose(found[ok], uv0[:50][ok], atol=1e-3)


def test_kept_reference_tiles_give_the_same_alignment(pair):
    """``IncrementalSfm`` keeps a landmark's reference tile for its next keyframes: the result
    must be what cutting it afresh gives, also for planes seen at a grazing angle (their
    pixels off the plane's plausible depth fall back to fronto-parallel)."""
    greys, T, K, uv0, X, _ = pair
    cfg = lr.RefineConfig()
    rng = np.random.default_rng(1)
    normals = rng.normal(size=X[:80].shape)  # random planes: some patches partly grazing
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    args = greys[0], greys[1], T[0], T[1], K, X[:80], normals, uv0[:80], cfg
    fresh = lr.align(*args)
    kept = lr.align(*args, tiles=lr.ref_tiles(greys[0], uv0[:80], cfg))
    np.testing.assert_array_equal(fresh[0], kept[0])
    np.testing.assert_array_equal(fresh[1], kept[1])


def _landmark_errors(engine, seq, renderer) -> np.ndarray:
    """Distance (m) of each landmark seen by >= 3 keyframes, after a Sim(3) of the keyframe
    centres onto the truth, from the true surface point behind its first observation."""
    from absscale_ros.core import align
    m = engine.current.map
    ids, T = m.poses()
    s, R, t = align.umeyama(T[:, :3, 3], seq.T_world_cams[ids, :3, 3])
    K, errs = engine.K, []
    for lm in m.landmarks.values():
        if lm.label is not None or len(lm.obs_px) < 3:
            continue
        k = min(lm.obs_px)
        ray = np.append((lm.obs_px[k] - K[:2, 2]) / np.diag(K)[:2], 1.0)
        ray /= np.linalg.norm(ray)
        Tk = seq.T_world_cams[k]
        dist, _ = renderer.cast(Tk, ray[None].astype(np.float32))
        if np.isfinite(dist[0]):
            truth = Tk[:3, 3] + Tk[:3, :3] @ ray * float(dist[0])
            errs.append(np.linalg.norm(align.apply(s, R, t, lm.point_world[None])[0] - truth))
    return np.array(errs)


def test_sfm_with_refined_observations_is_more_accurate():
    from dataclasses import replace
    from absscale_ros.core import sfm
    seq = sfm_scenes.make_sequence('outdoor_cube', 1, count=8, width=1280)
    renderer = render.Renderer(scenes.build_scene('outdoor_cube', 1), seq.camera)
    errs, moved = {}, {}
    for budget in (0, 2000):
        cfg = replace(sfm.SfmConfig(), refine_cfg=lr.RefineConfig(max_observations=budget))
        engine = sfm.IncrementalSfm(seq.camera, cfg, np.random.default_rng(7))
        results = [engine.add_keyframe(k, img) for k, img in enumerate(seq.images_bgr)]
        assert results[-1].keyframes == 8 and results[-1].segments == 1
        moved[budget] = sum(int(r.message.split(' observations refined')[0].rsplit(' ', 1)[1])
                            for r in results if 'observations refined' in r.message)
        errs[budget] = _landmark_errors(engine, seq, renderer)
        assert len(engine._refiner.grey) <= cfg.refine_cfg.keep_images
    print({b: (len(e), np.median(e), np.percentile(e, 90)) for b, e in errs.items()}, moved)
    assert moved[0] == 0 and moved[2000] > 1000
    assert np.median(errs[2000]) < 0.9 * np.median(errs[0])


def test_pairs_aligned_together_as_one_by_one(pair):
    """``ObservationRefiner`` aligns all of a keyframe's (reference, keyframe) pairs in one
    ``align_pairs`` call: each pair's result must be what ``align`` alone gives it (its
    Lucas-Kanade mosaic and warps the same)."""
    greys, T, K, uv0, X, _ = pair
    cfg = lr.RefineConfig()
    normals = lr.plane_normals(X, X, cfg.neighbours)
    parts = [(greys[1], T[1], slice(0, 60)), (greys[0], T[0], slice(60, 90)),
             (greys[1], T[1], slice(90, 140))]
    alone = [lr.align(greys[0], img, T[0], Tk, K, X[p], normals[p], uv0[p], cfg)
             for img, Tk, p in parts]
    together = lr.align_pairs([(img, T[0], Tk, p.stop - p.start) for img, Tk, p in parts], K,
                              X[:140], normals[:140], uv0[:140], lr.ref_tiles(greys[0], uv0[:140],
                                                                              cfg), cfg)
    np.testing.assert_array_equal(np.concatenate([a[0] for a in alone]), together[0])
    np.testing.assert_array_equal(np.concatenate([a[1] for a in alone]), together[1])
    assert together[1].mean() > 0.5


def test_more_patches_than_one_remap_takes(pair):
    """cv2.remap takes fewer than 2^15 rows (~760 tiles of 43 px): a keyframe refining more
    observations of one reference must still get each tile as if cut alone."""
    greys, _, _, uv0, _, _ = pair
    cfg = lr.RefineConfig()
    uv = np.resize(uv0, (900, 2))
    tiles = lr.ref_tiles(greys[0], uv, cfg)
    assert tiles.shape[0] == 900
    np.testing.assert_array_equal(tiles[850], lr.ref_tiles(greys[0], uv[850:851], cfg)[0])


def test_pair_counts_must_add_up(pair):
    greys, T, K, uv0, X, _ = pair
    cfg = lr.RefineConfig()
    normals = lr.plane_normals(X[:20], X[:20], 5)
    with pytest.raises(ValueError, match='19 patches, not 20'):
        lr.align_pairs([(greys[1], T[0], T[1], 19)], K, X[:20], normals, uv0[:20],
                       lr.ref_tiles(greys[0], uv0[:20], cfg), cfg)
