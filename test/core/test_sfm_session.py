"""The sfm node's map without ROS: the core's map, its bookkeeping, report and diagnosis."""
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
import itertools
import json
from pathlib import Path
import sys

from absscale_ros.core import keyframes, sfm, sfm_session
from absscale_ros.tools import bench_sfm
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
import sfm_scenes  # noqa: E402


def _ticks() -> itertools.count:
    return itertools.count(0.0, 0.002)  # a clock advancing 2 ms per reading


def test_the_session_map_is_the_cores_and_its_report_counts_it() -> None:
    seq = sfm_scenes.make_sequence('indoor_paper', 1, count=6)
    ticks = _ticks()
    session = sfm_session.SfmSession(sfm.SfmConfig(), 0, lambda: next(ticks))
    engine = sfm.IncrementalSfm(seq.camera, sfm.SfmConfig(), np.random.default_rng(0))
    rng_a, rng_b = np.random.default_rng(5), np.random.default_rng(5)
    with ThreadPoolExecutor(1) as pool:
        for k, image in enumerate(seq.images_bgr):
            # From the second keyframe on, features detected ahead (as the node's worker does).
            features = pool.submit(session.engine.detect, image) if k else None
            session.add(k + 1, image, sfm_scenes.detections(seq, k, rng_a)[0], None, features,
                        seq.camera, defer_batch=False)
            engine.add_keyframe(k + 1, image, sfm_scenes.detections(seq, k, rng_b)[0])
    assert session.engine.camera is seq.camera and session.features_prefetched == 5
    ids, T = engine.current.map.poses()
    ids_s, T_s = session.engine.current.map.poses()
    assert list(ids_s) == list(ids) and np.allclose(T_s, T, atol=1e-9)
    r = session.report(skipped=3, live={'batch_ms': [1.0]})
    assert r['keyframes_in'] == r['keyframes_registered'] == 6 and r['segments'] == 1
    assert r['keyframe_stamps_ns'] == [1, 2, 3, 4, 5, 6] and r['keyframes_skipped'] == 3
    assert r['update_ms'] == [2.0] * 6 and r['update_ms_median'] == pytest.approx(2.0)
    assert sum(r['statuses'].values()) == 6 and r['statuses'].get('registered', 0) >= 3
    assert r['batch_ms'] == [1.0] and r['target_vertices'] >= 3
    assert r['reprojection_rms_px'] <= 1.0
    brief = session.report(full_rms=False, live={'batch_ms': [1.0]})
    assert 'update_ms' not in brief and 'batch_ms' not in brief and brief['landmarks'] > 0
    assert brief['reprojection_rms_px'] == session.last.reprojection_rms_px
    assert session.diagnosis(brief, brief['target_vertices']) == ('ok', session.last.message)
    assert session.diagnosis(brief, 0)[0] == 'warn'


def test_rotation_only_warns_and_a_calibration_of_another_size_is_not_used() -> None:
    seq = sfm_scenes.make_sequence('outdoor_cube', 2, count=4, arc_deg=30.0, rotate_only=True)
    ticks = _ticks()
    session = sfm_session.SfmSession(sfm.SfmConfig(), 0, lambda: next(ticks))
    assert session.diagnosis(session.report(False), 0) == (
        'warn', 'no reconstruction yet (camera only rotating?): no keyframe yet')
    for k, image in enumerate(seq.images_bgr):
        session.add(k, image, None, None, None, seq.camera, defer_batch=False)
    r = session.report(full_rms=False)
    assert r['keyframes_registered'] == 0 and r['keyframes_in'] == 4
    level, text = session.diagnosis(r, 0)
    assert level == 'warn' and 'rotat' in text
    assert not session.adjust_if_due()  # nothing initialised: no batch is due
    # A calibration of another image size is not used: a nominal camera of the image's size.
    other = sfm_session.SfmSession(sfm.SfmConfig(), 0, lambda: next(ticks))
    half = replace(seq.camera, width=seq.camera.width // 2, height=seq.camera.height // 2)
    other.add(0, seq.images_bgr[0], None, None, None, half, defer_batch=False)
    assert (other.engine.camera.width, other.engine.camera.height) == \
        (seq.camera.width, seq.camera.height) and other.engine.camera is not half


def test_the_report_keeps_each_keyframes_tracked_step_for_the_replay(tmp_path) -> None:
    seq = sfm_scenes.make_sequence('indoor_paper', 1, count=3)
    ticks = _ticks()
    session = sfm_session.SfmSession(sfm.SfmConfig(), 0, lambda: next(ticks))
    rng = np.random.default_rng(5)
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    steps = [None, keyframes.TrackedStep(10**18 + 1, turn, np.array([0.1, -0.02, 0.3])), None]
    for k, image in enumerate(seq.images_bgr):
        session.add(10**18 + k + 1, image, sfm_scenes.detections(seq, k, rng)[0], steps[k],
                    None, seq.camera, defer_batch=False)
    report = tmp_path / 'report.json'  # through JSON, as absscale run writes it
    report.write_text(json.dumps({'nodes': {'sfm': session.report()}}))
    got = bench_sfm.run_keyframe_steps(str(report))
    assert list(got) == [10**18 + 2]  # the stamp survives JSON exactly (no float round trip)
    step = got[10**18 + 2]
    assert step.ref_stamp_ns == 10**18 + 1
    assert np.array_equal(step.rotation, turn) and np.array_equal(step.centre, [0.1, -0.02, 0.3])
