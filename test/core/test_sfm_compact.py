"""
Compacting finished map segments (issue 8: a long scan's memory) must not change any result.

A rendered orbit, a tracking loss (blank keyframes), then the orbit again: two segments, the
first finished. One engine compacts after every keyframe, as the sfm node does; its twin does
not. Both must publish, report and finally adjust exactly the same.
"""
from pathlib import Path
import sys

import numpy as np
import pytest

from absscale_ros.core import sfm, sfm_map, sfm_outputs

sys.path.insert(0, str(Path(__file__).parent))
import sfm_scenes  # noqa: E402


def _feed(seq: sfm_scenes.Sequence, compact: bool) -> sfm.IncrementalSfm:
    engine = sfm.IncrementalSfm(seq.camera, sfm.SfmConfig(), np.random.default_rng(7))
    rng = np.random.default_rng(5)
    blank = np.full_like(seq.images_bgr[0], 128)  # no features: the camera is "lost"
    frames = [(img, sfm_scenes.detections(seq, k, rng)[0]) for k, img in
              enumerate(seq.images_bgr)]
    for k, (img, vertices) in enumerate(frames + [(blank, None)] * 2 + frames):
        engine.add_keyframe(k, img, vertices)
        if compact:
            sfm_outputs.compact(engine)
    return engine


def _landmarks_equal(a: dict[int, sfm_map.Landmark], b: dict[int, sfm_map.Landmark]) -> None:
    assert list(a) == list(b)
    for la, lb in zip(a.values(), b.values()):
        assert np.array_equal(la.point_world, lb.point_world)
        assert la.colour_rgb == lb.colour_rgb and la.label == lb.label
        assert list(la.obs_px) == list(lb.obs_px)
        assert all(np.array_equal(la.obs_px[k], lb.obs_px[k]) for k in la.obs_px)


@pytest.fixture(scope='module')
def engines() -> tuple[sfm.IncrementalSfm, sfm.IncrementalSfm]:
    seq = sfm_scenes.make_sequence('outdoor_cube', 2, count=8)
    return _feed(seq, compact=False), _feed(seq, compact=True)


def test_finished_segment_is_frozen_and_outputs_unchanged(engines) -> None:
    plain, compacted = engines
    assert len(plain.segments) == len(compacted.segments) == 2
    first, best = compacted.segments[0].map, sfm_outputs.best_segment(compacted).map
    assert first.frozen and best is compacted.current.map and not best.frozen
    ref = plain.segments[0].map
    # Read without unpacking: the published segment's choice and the report's counts.
    assert first.landmark_count() == len(ref.landmarks) > 100
    assert first.vertex_count() == sum(lm.label is not None for lm in ref.landmarks.values()) > 0
    assert first.frozen
    # The colour windows only the newest keyframes' vertex linking reads went.
    old = [kf for kf in best.keyframes.values() if kf.vertices is not None and
           not len(kf.features.points_px)]
    assert all(w is None for kf in old for w in kf.vertices.windows)
    for a, b in ((sfm_outputs.cloud(best, compacted.K, compacted.cfg.cloud_cfg),
                  sfm_outputs.cloud(plain.current.map, plain.K, plain.cfg.cloud_cfg)),
                 (sfm_outputs.path(best), sfm_outputs.path(plain.current.map))):
        assert all(np.array_equal(x, y) for x, y in zip(a, b))


def test_unfrozen_map_is_the_same_and_adjusts_the_same(engines) -> None:
    plain, compacted = engines
    first, ref = compacted.segments[0].map, plain.segments[0].map
    _landmarks_equal(first.landmarks, ref.landmarks)  # the access unpacks
    assert not first.frozen
    for kf, kf_ref in zip(first.keyframes.values(), ref.keyframes.values()):
        assert kf.landmark_of.dtype == np.int64 and np.array_equal(kf.landmark_of,
                                                                   kf_ref.landmark_of)
    a, b = compacted.finish(), plain.finish()
    assert a == b
    for m in (seg.map for e in engines for seg in e.segments):  # culled by the batches too
        assert m.vertex_count() == sum(lm.label is not None for lm in m.landmarks.values()) > 0
    for seg, seg_ref in zip(compacted.segments, plain.segments):
        _landmarks_equal(seg.map.landmarks, seg_ref.map.landmarks)
        assert np.array_equal(seg.map.poses()[1], seg_ref.map.poses()[1])


def test_pack_round_trip_of_an_empty_map() -> None:
    m = sfm_map.SfmMap()
    m.freeze()
    assert m.frozen and m.landmark_count() == 0 == m.vertex_count()
    assert m.landmarks == {} and not m.frozen


def test_vertex_count_follows_removals_and_packing() -> None:
    m = sfm_map.SfmMap()
    ids = [m.add_landmark(np.zeros(3), (0, 0, 0), (1, k) if k % 2 else None) for k in range(6)]
    assert m.vertex_count() == 3
    m.remove_landmark(ids[1])
    assert m.vertex_count() == 2
    m.freeze()
    assert m.vertex_count() == 2 and m.frozen
    m.remove_landmark(ids[3])  # unpacks
    assert m.vertex_count() == 1
