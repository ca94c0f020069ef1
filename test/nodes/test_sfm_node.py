"""The sfm node as a real rclpy node: keyframes and their vertices in, map topics out."""
from pathlib import Path
import sys

from absscale_ros import conversions
from absscale_ros.core import detect, keyframes, replay, sfm, sfm_outputs
from absscale_ros.core.types import CameraModel
from absscale_ros.nodes import common
from absscale_ros.nodes.sfm import SfmNode
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import TransformStamped
from nav_msgs.msg import Path as PathMsg
import numpy as np
import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from ros_helpers import spin_until
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from std_msgs.msg import Header

sys.path.insert(0, str(Path(__file__).parents[1] / 'core'))
import sfm_scenes  # noqa: E402

OUTPUTS = ('/absscale/sparse_cloud', '/absscale/keyframe_path', '/absscale/target_points')


class Probe(Node):
    """Publishes keyframes, vertices, tracked steps and camera_info; records outputs,
    diagnostics and acks."""

    def __init__(self, **kwargs) -> None:
        super().__init__('probe', **kwargs)
        self.got: dict[str, list] = {t: [] for t in OUTPUTS}
        for topic, cls in zip(OUTPUTS, (PointCloud2, PathMsg, PointCloud2)):
            self.create_subscription(cls, topic, self.got[topic].append, common.RELIABLE)
        self.diags: list[DiagnosticArray] = []
        # Only ours: another run on this machine may share the DDS domain.
        self.create_subscription(DiagnosticArray, '/diagnostics', lambda m: self.diags.append(m)
                                 if m.status[0].name.startswith('sfm') else None, 100)
        self.acks: list[replay.Ack] = []
        self.create_subscription(Header, common.ACK_TOPIC, lambda m: self.acks.append(
            replay.Ack.decode(m.frame_id, conversions.stamp_to_ns(m.stamp))), common.RELIABLE)
        self.info = self.create_publisher(CameraInfo, '/absscale/camera_info', common.RELIABLE)
        self.kf = self.create_publisher(Image, '/absscale/keyframes', common.RELIABLE)
        self.kv = self.create_publisher(PointCloud2, '/absscale/keyframe_vertices',
                                        common.RELIABLE)
        self.motion = self.create_publisher(TransformStamped, '/absscale/keyframe_motion',
                                            common.RELIABLE)

    def send(self, camera: CameraModel, stamp_ns: int, image: np.ndarray,
             vertices: np.ndarray, step: keyframes.TrackedStep | None) -> None:
        self.info.publish(conversions.camera_model_to_info_msg(camera, stamp_ns, 'cam'))
        self.motion.publish(conversions.tracked_step_to_msg(step, stamp_ns))
        self.kv.publish(conversions.array_to_cloud_msg(vertices, stamp_ns, 'cam'))
        self.kf.publish(conversions.array_to_image_msg(image, 'bgr8', stamp_ns, 'cam'))


def _rows(vertices) -> np.ndarray:
    rows = np.zeros(len(vertices.object_ids), detect.VERTEX_DTYPE)
    rows['u'], rows['v'] = vertices.points_px[:, 0], vertices.points_px[:, 1]
    rows['object_id'], rows['vertex_id'] = vertices.object_ids, vertices.vertex_ids
    rows['target_type'] = [0 if k == 'sheet' else 1 for k in vertices.kinds]
    return rows


def _tracked(seq: sfm_scenes.Sequence, k: int, stamps: list[int]) -> keyframes.TrackedStep | None:
    """The true step to keyframe ``k`` from the one before, as the selector would track it."""
    if k == 0:
        return None
    rel = np.linalg.inv(seq.T_world_cams[k - 1]) @ seq.T_world_cams[k]
    return keyframes.TrackedStep(stamps[k - 1], rel[:3, :3].T, rel[:3, 3])


def _run(context, seq: sfm_scenes.Sequence, with_vertices: bool) -> tuple[SfmNode, Probe]:
    node, probe = SfmNode(context=context), Probe(context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    executor.add_node(probe)
    assert spin_until(executor, lambda: probe.kf.get_subscription_count() > 0)
    rng = np.random.default_rng(5)
    stamps = [(k + 1) * 100_000_000 for k in range(len(seq.images_bgr))]
    for k, image in enumerate(seq.images_bgr):
        stamp_ns = stamps[k]
        vertices = _rows(sfm_scenes.detections(seq, k, rng)[0]) if with_vertices else \
            np.zeros(0, detect.VERTEX_DTYPE)
        probe.send(seq.camera, stamp_ns, image, vertices, _tracked(seq, k, stamps))
        # Step mode: the next keyframe only once this one is acknowledged on all three inputs.
        assert spin_until(executor, lambda: sum(a.stamp_ns == stamp_ns for a in probe.acks) == 3,
                          timeout_s=30.0)
    spin_until(executor, lambda: len(probe.diags) >= len(seq.images_bgr), timeout_s=2.0)
    return node, probe


def test_map_topics_match_the_core_and_every_input_is_acknowledged(context) -> None:
    seq = sfm_scenes.make_sequence('indoor_paper', 1, count=6)
    node, probe = _run(context, seq, with_vertices=True)
    stamps = [(k + 1) * 100_000_000 for k in range(len(seq.images_bgr))]
    for a in probe.acks:
        assert a.node == 'sfm' and set(a.outputs) == set(OUTPUTS)
    assert sorted({a.stamp_ns for a in probe.acks}) == stamps
    for topic in OUTPUTS:
        assert [conversions.stamp_to_ns(m.header.stamp) for m in probe.got[topic]] == stamps
    # The same keyframes through the core alone give the same map (its vertices as the node
    # gets them: float32 px in the message; a 1e-5 px difference can flip a match).
    engine = sfm.IncrementalSfm(seq.camera, sfm.SfmConfig(), np.random.default_rng(0))
    rng = np.random.default_rng(5)
    for k, image in enumerate(seq.images_bgr):
        vertices = sfm_outputs.vertices_from_rows(_rows(sfm_scenes.detections(seq, k, rng)[0]))
        engine.add_keyframe(stamps[k], image, vertices, _tracked(seq, k, stamps))
    poses, pose_stamps = conversions.path_msg_to_poses(probe.got[OUTPUTS[1]][-1])
    ids, T = engine.current.map.poses()
    assert list(pose_stamps) == [engine.current.map.keyframes[i].stamp_ns for i in ids]
    assert np.allclose(poses[:, :3], T[:, :3, 3], atol=1e-5)
    cloud = conversions.cloud_msg_to_array(probe.got[OUTPUTS[0]][-1])
    # Only the well-triangulated landmarks are published (``cloud.*`` parameters).
    xyz, _ = sfm_outputs.cloud(engine.current.map, engine.K, sfm.SfmConfig().cloud_cfg)
    assert 0 < len(cloud) == len(xyz) < len(engine.current.map.landmarks)
    assert 'rgb' in cloud.dtype.names
    assert np.allclose(np.stack([cloud[a] for a in 'xyz'], axis=1), xyz, atol=1e-4)
    targets = conversions.cloud_msg_to_array(probe.got[OUTPUTS[2]][-1])
    assert len(targets) >= 3 and set(targets['target_type']) == {0}
    assert np.all(targets['n_obs'] >= 2) and np.all(targets['angle_deg'] > 1.0)
    r = node.report()
    assert r['keyframes_in'] == 6 and r['keyframes_registered'] == 6 and r['segments'] == 1
    # Features of all but the first keyframe (it makes the engine) came from the worker
    # thread, and the map is the core's to the digit.
    assert node.session.features_prefetched == 5
    assert r['reprojection_rms_px'] <= 1.0 and r['update_ms_median'] > 0.0
    assert r['target_vertices'] == len(targets)
    status = probe.diags[-1].status[0]
    assert status.level == b'\x00' and conversions.diagnostic_values(status)['landmarks'] == \
        str(len(engine.current.map.landmarks))


def test_the_end_of_bag_publishes_the_finished_map(context) -> None:
    """Offline, the replay's end: the final batch adjustment, then the map once more (what
    the scale node estimates last), equal to the core's map after ``finish``."""
    seq = sfm_scenes.make_sequence('indoor_paper', 1, count=6)
    node, probe = _run(context, seq, with_vertices=True)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    executor.add_node(probe)
    end = probe.create_publisher(Header, common.END_OF_BAG_TOPIC, common.RELIABLE)
    assert spin_until(executor, lambda: end.get_subscription_count() > 0)
    end_ns = 7 * 100_000_000
    end.publish(conversions.end_of_bag_msg(end_ns))
    assert spin_until(executor, lambda: any(a.stamp_ns == end_ns for a in probe.acks),
                      timeout_s=30.0)
    ack = next(a for a in probe.acks if a.stamp_ns == end_ns)
    assert ack.input_topic == common.END_OF_BAG_TOPIC and set(ack.outputs) == set(OUTPUTS)
    assert spin_until(executor, lambda: all(
        conversions.stamp_to_ns(probe.got[t][-1].header.stamp) == end_ns for t in OUTPUTS))
    stamps = [(k + 1) * 100_000_000 for k in range(len(seq.images_bgr))]
    engine = sfm.IncrementalSfm(seq.camera, sfm.SfmConfig(), np.random.default_rng(0))
    rng = np.random.default_rng(5)
    for k, image in enumerate(seq.images_bgr):
        vertices = sfm_outputs.vertices_from_rows(_rows(sfm_scenes.detections(seq, k, rng)[0]))
        engine.add_keyframe(stamps[k], image, vertices, _tracked(seq, k, stamps))
    min_angle = sfm.SfmConfig().vertex_cfg.publish_min_angle_deg
    before = sfm_outputs.target_points(engine.current.map, min_angle).points.copy()
    engine.finish()
    tp = sfm_outputs.target_points(engine.current.map, min_angle)
    got = conversions.cloud_msg_to_array(probe.got[OUTPUTS[2]][-1])
    assert len(got) == len(tp.points) >= 3
    xyz = np.stack([got[a] for a in 'xyz'], axis=1)
    assert np.allclose(xyz, tp.points, atol=1e-5)
    assert list(got['vertex_id']) == list(tp.vertex_ids)
    # The adjustment moved them (else this test could not tell the maps apart).
    assert before.shape != tp.points.shape or \
        np.max(np.linalg.norm(before - tp.points, axis=1)) > 1e-4
    assert node.report()['final_batch_ms'] > 0.0


@pytest.mark.parametrize('rotate_only', [True, False])
def test_rotation_only_and_no_target_end_with_a_warning(context, rotate_only: bool) -> None:
    seq = sfm_scenes.make_sequence('outdoor_cube', 2, count=4, arc_deg=30.0,
                                   rotate_only=rotate_only)
    node, probe = _run(context, seq, with_vertices=False)
    status = probe.diags[-1].status[0]
    assert status.level == b'\x01'  # WARN, and no exception on the way
    if rotate_only:
        assert 'rotat' in status.message and node.report()['keyframes_registered'] == 0
    else:
        assert 'no target vertex' in status.message
        assert node.report()['keyframes_registered'] >= 3
    assert len(probe.got['/absscale/target_points'][-1].data) == 0
