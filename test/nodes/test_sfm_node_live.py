"""A live sfm node that is behind: keyframes do not queue, the newest one is taken."""
from pathlib import Path
import sys
import threading

from absscale_ros import conversions
from absscale_ros.core import sfm, sfm_outputs
from absscale_ros.nodes.sfm import SfmNode
import numpy as np
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from ros_helpers import spin_until
from test_sfm_node import _rows, _tracked, OUTPUTS, Probe

sys.path.insert(0, str(Path(__file__).parents[1] / 'core'))
import sfm_scenes  # noqa: E402


def test_a_live_sfm_behind_takes_the_newest_keyframe_and_chains_the_skipped_steps(
        context, monkeypatch) -> None:
    seq = sfm_scenes.make_sequence('indoor_paper', 1, count=6)
    stamps = [(k + 1) * 100_000_000 for k in range(len(seq.images_bgr))]
    # The first update holds until every keyframe has arrived: the node is behind for sure.
    release, steps = threading.Event(), {}
    add_keyframe = sfm.IncrementalSfm.add_keyframe

    def slow_add(engine, stamp_ns, image, vertices=None, step=None, features=None, **kw):
        release.wait(timeout=30.0)
        steps[stamp_ns] = step
        return add_keyframe(engine, stamp_ns, image, vertices, step, features, **kw)

    monkeypatch.setattr(sfm.IncrementalSfm, 'add_keyframe', slow_add)
    node = SfmNode(context=context, parameter_overrides=[Parameter('qos', value='sensor_data')])
    probe = Probe(context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    executor.add_node(probe)
    try:
        assert spin_until(executor, lambda: probe.kf.get_subscription_count() > 0)
        rng = np.random.default_rng(5)
        for k, image in enumerate(seq.images_bgr):
            probe.send(seq.camera, stamps[k], image, _rows(sfm_scenes.detections(seq, k, rng)[0]),
                       _tracked(seq, k, stamps))
        # Keyframe 0 is being added; 1-4 were each replaced by a newer one while waiting.
        assert spin_until(executor, lambda: node.live.skipped == 4, timeout_s=30.0)
        release.set()
        assert spin_until(executor, lambda: len(probe.got[OUTPUTS[1]]) == 2, timeout_s=30.0)
        spin_until(executor, lambda: False, timeout_s=0.5)  # nothing else comes
    finally:
        release.set()
        executor.shutdown()
        node.destroy_node()
    for topic in OUTPUTS:  # the map answered keyframe 0 and then the newest
        assert [conversions.stamp_to_ns(m.header.stamp) for m in probe.got[topic]] == \
            [stamps[0], stamps[-1]]
    assert sorted(steps) == [stamps[0], stamps[-1]] and steps[stamps[0]] is None
    # The newest keyframe's tracked step starts at keyframe 0: the five steps chained.
    step = steps[stamps[-1]]
    rel = np.linalg.inv(seq.T_world_cams[0]) @ seq.T_world_cams[-1]
    assert step.ref_stamp_ns == stamps[0]
    assert np.allclose(step.rotation, rel[:3, :3].T, atol=1e-6)
    assert np.allclose(step.centre, rel[:3, 3], atol=1e-6)
    r = node.report()
    assert r['keyframes_in'] == 2 and r['keyframes_skipped'] == 4
    assert r['keyframe_stamps_ns'] == [stamps[0], stamps[-1]]  # what an offline replay takes
    values = conversions.diagnostic_values(probe.diags[-1].status[0])
    assert values['keyframes_skipped'] == '4'  # the user sees it


def test_a_live_sfm_adjusts_after_publishing_and_keeps_the_offline_map(context) -> None:
    """Keyframes one at a time, each once the last is done: none skipped, and the batch
    adjustment a due update left for later gives the map the core gives offline (there the
    batch is inside the update)."""
    seq = sfm_scenes.make_sequence('indoor_paper', 1, count=6)
    stamps = [(k + 1) * 100_000_000 for k in range(len(seq.images_bgr))]
    node = SfmNode(context=context, parameter_overrides=[
        Parameter('qos', value='sensor_data'), Parameter('graph.batch_every', value=3)])
    probe = Probe(context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    executor.add_node(probe)
    rng = np.random.default_rng(5)
    try:
        assert spin_until(executor, lambda: probe.kf.get_subscription_count() > 0)
        for k, image in enumerate(seq.images_bgr):
            probe.send(seq.camera, stamps[k], image, _rows(sfm_scenes.detections(seq, k, rng)[0]),
                       _tracked(seq, k, stamps))
            # Idle again (a due batch adjustment included) before the next keyframe comes.
            assert spin_until(executor, lambda: len(probe.got[OUTPUTS[1]]) == k + 1
                              and not node.live.busy, timeout_s=30.0)
    finally:
        executor.shutdown()
        node.destroy_node()
    assert node.live.skipped == 0 and len(node.live.batch_ms) >= 1
    cfg = sfm.SfmConfig()
    cfg = sfm.replace(cfg, graph_cfg=sfm.replace(cfg.graph_cfg, batch_every=3))
    engine = sfm.IncrementalSfm(seq.camera, cfg, np.random.default_rng(0))
    rng = np.random.default_rng(5)
    for k, image in enumerate(seq.images_bgr):
        engine.add_keyframe(stamps[k], image, sfm_outputs.vertices_from_rows(
            _rows(sfm_scenes.detections(seq, k, rng)[0])), _tracked(seq, k, stamps))
    # The node's map after its last deferred adjustment (its last path went out before it).
    ids, T = engine.current.map.poses()
    node_ids, node_T = node.session.engine.current.map.poses()
    assert len(ids) == len(node_ids) == 6
    assert np.allclose(node_T[:, :3, 3], T[:, :3, 3], atol=1e-5)
