"""
sfm: an unscaled incremental reconstruction from the keyframes (``core/sfm.py``).

Subscribes ``/absscale/keyframes`` (Image), ``/absscale/keyframe_vertices`` (PointCloud2) and,
with ``use_tracked_steps``, ``/absscale/keyframe_motion`` (TransformStamped: the selector's
tracked step, against which a registration is checked), paired by stamp, and
``/absscale/camera_info``. After each keyframe publishes, for the segment
worth scaling (``core/sfm_outputs.best_segment``): ``/absscale/sparse_cloud`` (x y z rgb, SfM
units), ``/absscale/keyframe_path`` (nav_msgs/Path, T_world_cam per keyframe),
``/absscale/target_points`` (x y z object_id vertex_id n_obs angle_deg target_type) and
``/diagnostics``. A keyframe's features are detected on a worker thread as soon as its image
arrives (OpenCV releases the GIL), while its vertices are still on their way or the previous
keyframe is being added. Live (``qos: sensor_data``) the map is updated on a worker thread and
keyframes do not queue: one that arrives while another waits replaces it (the tracked steps of
those skipped are chained into the next one's, so its check still holds), and
``keyframes_skipped`` counts them; the periodic batch adjustment waits until a keyframe's map
is published and no other keyframe waits. Parameters: the scalars of ``SfmConfig`` and its
stages as ``features.*``, ``twoview.*``, ``graph.*``, ``vertices.*``, ``local_map.*``,
``cloud.*`` (which landmarks are published), ``qos`` (``reliable``, or ``sensor_data`` live).
"""
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import fields, is_dataclass, replace
import threading
import time
from typing import Any

from absscale_ros import conversions
from absscale_ros.core import errors, keyframes, pairing, sfm, sfm_outputs
from absscale_ros.nodes import common
from geometry_msgs.msg import TransformStamped
from nav_msgs.msg import Path
import numpy as np
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image, PointCloud2


class SfmNode(Node):

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('sfm', **kwargs)
        cfg = sfm.SfmConfig()
        flat = {f.name: getattr(cfg, f.name) for f in fields(cfg)
                if not is_dataclass(getattr(cfg, f.name))}
        values = {k: self.declare_parameter(k, v).value for k, v in flat.items()}
        values.update({field: common.declare_config(self, getattr(cfg, field), prefix)
                       for prefix, field in sfm.PARAM_PREFIXES.items()})
        self._cfg = replace(cfg, **values)
        p = {x.name: x.value for x in self.declare_parameters('', [
            ('pair_depth', 10), ('seed', 0), ('frame_id', 'map'), ('use_tracked_steps', True),
            ('qos', 'reliable')])}
        self._seed, self._frame = p['seed'], p['frame_id']
        self.live = p['qos'] == common.LIVE
        self._pairer: pairing.StampPairer[Image, PointCloud2] = pairing.StampPairer(
            p['pair_depth'])
        self._step_pairer: pairing.StampPairer[tuple[Image, PointCloud2], TransformStamped] = \
            pairing.StampPairer(p['pair_depth'])
        self._camera: Any = None
        self.engine: sfm.IncrementalSfm | None = None
        self._last: sfm.UpdateResult | None = None
        self.statuses: dict[str, int] = {}
        self._times_ms: list[float] = []
        # Stamps of the keyframes the map was given (live: those not skipped), in order: the
        # core run over them offline replays what this map saw (`bench sfm --keyframes-from`).
        self.keyframe_stamps_ns: list[int] = []
        self._pubs = {name: self.create_publisher(cls, f'/absscale/{name}', common.RELIABLE)
                      for name, cls in (('sparse_cloud', PointCloud2), ('keyframe_path', Path),
                                        ('target_points', PointCloud2))}
        self._diag = common.DiagnosticsPublisher(self, 'reconstruction')
        self._ack = common.StepAck(self)
        group = MutuallyExclusiveCallbackGroup()  # the map is updated by one callback at a time
        self.create_subscription(CameraInfo, '/absscale/camera_info', self._on_info,
                                 common.RELIABLE, callback_group=group)
        self._detector = ThreadPoolExecutor(1, 'sfm_features')
        self._prefetched: dict[int, tuple[Any, Future]] = {}  # stamp -> (image, features)
        self.features_prefetched = 0  # keyframes whose features came from the worker
        # Live: the keyframe waiting for the update worker, and the skipped ones' steps.
        self._lock = threading.Lock()
        # Live: held while the worker changes the map, so a report from another thread (the
        # node's end) reads it whole; re-entrant, as an update's diagnostics report too.
        self._engine_lock = threading.RLock()
        self._waiting: tuple[Image, PointCloud2, TransformStamped | None] | None = None
        self._updating = False
        self._updater = ThreadPoolExecutor(1, 'sfm_update') if self.live else None
        self._skipped_steps: dict[int, keyframes.TrackedStep | None] = {}
        self.keyframes_skipped = 0
        # Live, per keyframe added: stamp, and when (monotonic ns, one clock for all processes)
        # its image arrived, its update started and ended: where a keyframe's latency goes.
        self._arrived_ns: dict[int, int] = {}
        self.timeline_ns: list[tuple[int, int, int, int]] = []
        self.batch_ms: list[float] = []  # live: the deferred batch adjustments
        self._kf_sub = self.create_subscription(
            Image, '/absscale/keyframes', self._on_keyframe, common.RELIABLE,
            callback_group=group)  # live too: _offer drops, knowing what it skipped
        self._kv_sub = self.create_subscription(
            PointCloud2, '/absscale/keyframe_vertices', lambda m: self._settle(
                self._pairer.add_second(conversions.stamp_to_ns(m.header.stamp), m)),
            common.RELIABLE, callback_group=group)
        self._motion_sub = self.create_subscription(
            TransformStamped, '/absscale/keyframe_motion', lambda m: self._settle_steps(
                self._step_pairer.add_second(conversions.stamp_to_ns(m.header.stamp), m)),
            common.RELIABLE, callback_group=group) if p['use_tracked_steps'] else None

    def _on_info(self, msg: CameraInfo) -> None:
        try:
            self._camera = conversions.camera_info_to_model(msg)
        except errors.AbsScaleError as err:
            self.get_logger().warning(f'bad camera_info: {err}', throttle_duration_sec=5.0)

    def destroy_node(self) -> None:
        if self._updater is not None:
            self._updater.shutdown(wait=True, cancel_futures=True)
        self._detector.shutdown(wait=False, cancel_futures=True)
        super().destroy_node()

    def _on_keyframe(self, msg: Image) -> None:
        stamp_ns = conversions.stamp_to_ns(msg.header.stamp)
        if self.live:
            with self._lock:
                self._arrived_ns[stamp_ns] = time.monotonic_ns()
        if self.engine is not None:  # the first keyframe makes the engine (camera) first
            try:
                image = conversions.image_msg_to_bgr(msg)
            except errors.AbsScaleError:
                image = None  # _process says why
            if image is not None and image.shape[:2] == (self.engine.camera.height,
                                                         self.engine.camera.width):
                with self._lock:  # live, the update worker takes them
                    self._prefetched[stamp_ns] = (image, self._detector.submit(
                        self.engine.detect, image))
                    while len(self._prefetched) > 2 * self._pairer.depth + 2:  # never paired
                        self._prefetched.pop(min(self._prefetched))[1].cancel()
        self._settle(self._pairer.add_first(stamp_ns, msg))

    def _settle(self, result: pairing.Pairing[Image, PointCloud2]) -> None:
        for stamp_ns, image, vertices in result.pairs:
            if self._motion_sub is not None:
                self._settle_steps(self._step_pairer.add_first(stamp_ns, (image, vertices)))
            else:
                self._handle(image, vertices, None)
        for _, msg in result.dropped_first:
            self.statuses['unpaired'] = self.statuses.get('unpaired', 0) + 1
            self._ack.ack(msg.header.stamp, self._kf_sub.topic_name)
        for _, msg in result.dropped_second:
            self._ack.ack(msg.header.stamp, self._kv_sub.topic_name)

    def _settle_steps(self, result: pairing.Pairing[tuple[Image, PointCloud2],
                                                    TransformStamped]) -> None:
        # A keyframe whose step never came is older than the pairs just made: first, unchecked.
        for _, (image, vertices) in result.dropped_first:
            self.statuses['no_tracked_step'] = self.statuses.get('no_tracked_step', 0) + 1
            self._handle(image, vertices, None)
        for _, (image, vertices), motion in result.pairs:
            self._handle(image, vertices, motion)
        for _, motion in result.dropped_second:
            self._ack.ack(motion.header.stamp, self._motion_sub.topic_name)

    def _handle(self, image: Image, vertices: PointCloud2,
                motion: TransformStamped | None) -> None:
        if self.live:
            self._offer(image, vertices, motion)
            return
        outputs = self._process(image, vertices, motion)
        self._ack.ack(image.header.stamp, self._kf_sub.topic_name, outputs)
        self._ack.ack(vertices.header.stamp, self._kv_sub.topic_name, outputs)
        if motion is not None:
            self._ack.ack(motion.header.stamp, self._motion_sub.topic_name, outputs)

    def _offer(self, image: Image, vertices: PointCloud2,
               motion: TransformStamped | None) -> None:
        """Live: hand a keyframe to the update worker; one still waiting is skipped."""
        with self._lock:
            stale, self._waiting = self._waiting, (image, vertices, motion)
            if stale is not None:
                self._skip(*stale)
            if self._updating:
                return
            self._updating = True
        assert self._updater is not None
        self._updater.submit(self._update_loop)

    def _skip(self, image: Image, vertices: PointCloud2,
              motion: TransformStamped | None) -> None:
        """A keyframe the live map will not see: keep its step to chain (under the lock)."""
        stamp_ns = conversions.stamp_to_ns(image.header.stamp)
        self.keyframes_skipped += 1
        entry = self._prefetched.pop(stamp_ns, None)
        if entry is not None:
            entry[1].cancel()  # not detected if the detector has not started it
        try:
            step = conversions.tracked_step_from_msg(motion) if motion else None
        except errors.AbsScaleError:
            step = None
        self._skipped_steps[stamp_ns] = step

    def _update_loop(self) -> None:
        """
        Live: add the waiting keyframe to the map until none waits; then the batch adjustment
        its update left out, if due (seconds, which no keyframe waits behind unless it comes
        meanwhile), and look again.
        """
        while True:
            with self._lock:
                item, self._waiting = self._waiting, None
            if item is None:
                if self._adjust_if_due():
                    continue
                with self._lock:
                    if self._waiting is None:
                        self._updating = False
                        return
                continue
            stamp_ns = conversions.stamp_to_ns(item[0].header.stamp)
            started = time.monotonic_ns()
            try:
                with self._engine_lock:
                    self._process(*item)
                with self._lock:
                    arrived = self._arrived_ns.pop(stamp_ns, started)
                    for old in [s for s in self._arrived_ns if s < stamp_ns]:
                        del self._arrived_ns[old]
                self.timeline_ns.append((stamp_ns, arrived, started, time.monotonic_ns()))
            except Exception as err:  # noqa: BLE001 (a worker's exception would vanish)
                self.get_logger().error(f'keyframe update failed: {err!r}')

    def _adjust_if_due(self) -> bool:
        """Live: run the batch adjustment the updates deferred, if due; whether it ran."""
        t0 = time.perf_counter()
        try:
            with self._engine_lock:
                culled = self.engine.adjust_if_due() if self.engine is not None else None
        except Exception as err:  # noqa: BLE001 (a worker's exception would vanish)
            self.get_logger().error(f'batch adjustment failed: {err!r}')
            return False
        if culled is not None:
            self.batch_ms.append(1e3 * (time.perf_counter() - t0))
        return culled is not None

    def _bridge(self, stamp_ns: int, step: keyframes.TrackedStep | None
                ) -> keyframes.TrackedStep | None:
        """Live: the step from the last keyframe the map saw, over the skipped ones."""
        with self._lock:
            while step is not None and step.ref_stamp_ns in self._skipped_steps:
                earlier = self._skipped_steps.pop(step.ref_stamp_ns)
                step = None if earlier is None else keyframes.chain(earlier, step)
            for old in [s for s in self._skipped_steps if s < stamp_ns]:
                del self._skipped_steps[old]
        return step

    def _process(self, image_msg: Image, vertices_msg: PointCloud2,
                 motion_msg: TransformStamped | None) -> list[str]:
        stamp_ns = conversions.stamp_to_ns(image_msg.header.stamp)
        with self._lock:
            image, features = self._prefetched.pop(stamp_ns, (None, None))
        try:
            image = conversions.image_msg_to_bgr(image_msg) if image is None else image
            rows = conversions.cloud_msg_to_array(vertices_msg)
            step = conversions.tracked_step_from_msg(motion_msg) if motion_msg else None
        except errors.AbsScaleError as err:
            self.get_logger().warning(f'keyframe dropped: {err}', throttle_duration_sec=5.0)
            return []
        if self.live:
            step = self._bridge(stamp_ns, step)
        if self.engine is None:
            h, w = image.shape[:2]
            camera = self._camera if self._camera is not None and \
                (self._camera.width, self._camera.height) == (w, h) \
                else keyframes.nominal_camera(w, h)
            self.engine = sfm.IncrementalSfm(camera, self._cfg, np.random.default_rng(self._seed))
        t0 = time.perf_counter()  # waiting for the prefetched features counts
        self._last = self.engine.add_keyframe(
            stamp_ns, image, sfm_outputs.vertices_from_rows(rows), step,
            features.result() if features is not None else None, defer_batch=self.live)
        self.features_prefetched += features is not None
        sfm_outputs.compact(self.engine)  # finished segments to arrays: memory of long scans
        self._times_ms.append(1e3 * (time.perf_counter() - t0))
        self.keyframe_stamps_ns.append(stamp_ns)
        self.statuses[self._last.status] = self.statuses.get(self._last.status, 0) + 1
        return self._publish(stamp_ns)

    def _publish(self, stamp_ns: int) -> list[str]:
        assert self.engine is not None
        m = sfm_outputs.best_segment(self.engine).map
        xyz, rgb = sfm_outputs.cloud(m, self.engine.K, self._cfg.cloud_cfg)
        stamps, poses = sfm_outputs.path(m)
        tp = sfm_outputs.target_points(m)
        msgs = {'sparse_cloud': conversions.xyz_rgb_to_cloud_msg(xyz, rgb, stamp_ns, self._frame),
                'keyframe_path': conversions.poses_to_path_msg(poses, stamps, self._frame,
                                                               stamp_ns),
                'target_points': conversions.xyz_rgb_to_cloud_msg(
                    tp.points, None, stamp_ns, self._frame, extra={
                        'object_id': tp.object_ids, 'vertex_id': tp.vertex_ids,
                        'n_obs': tp.n_obs, 'angle_deg': tp.angle_deg,
                        'target_type': tp.target_types})}
        for name, msg in msgs.items():  # target_points last: scale reads cloud and path then
            self._pubs[name].publish(msg)
        self._diagnose(stamp_ns, len(tp.points))
        return [self._pubs[name].topic_name for name in msgs]

    def _diagnose(self, stamp_ns: int, vertices: int) -> None:
        r = self.report(full_rms=False)
        level, text = 'ok', self._last.message if self._last else 'no keyframe yet'
        if r['keyframes_registered'] == 0:
            level, text = 'warn', f'no reconstruction yet (camera only rotating?): {text}'
        elif vertices == 0:
            level, text = 'warn', ('no target vertex reconstructed yet (target not seen from '
                                   f'two keyframes with parallax); {text}')
        self._diag.publish(level, text, {**r, 'target_vertices': vertices}, stamp_ns)

    def report(self, full_rms: bool = True) -> dict[str, Any]:
        """
        Keyframes, segments, reprojection and update times, for report.json.

        :param full_rms: RMS over the whole published segment (else over its newest three
            keyframes: cheap enough for every keyframe).
        """
        with self._engine_lock:
            return self._report(full_rms)

    def _report(self, full_rms: bool) -> dict[str, Any]:
        times = np.array(self._times_ms or [np.nan])
        out: dict[str, Any] = {'keyframes_in': len(self._times_ms), 'keyframes_registered': 0,
                               'keyframes_skipped': self.keyframes_skipped,
                               'segments': 0, 'landmarks': 0, 'target_vertices': 0,
                               'reprojection_rms_px': float('nan'),
                               'update_ms_median': float(np.median(times)),
                               'update_ms_p95': float(np.percentile(times, 95)),
                               'statuses': dict(self.statuses)}
        if full_rms:  # the whole run (not in every keyframe's diagnostics)
            out['update_ms'] = [round(t, 1) for t in self._times_ms]
            out['keyframe_stamps_ns'] = list(self.keyframe_stamps_ns)
            if self.live:
                out['timeline_ns'] = list(self.timeline_ns)
                out['batch_ms'] = [round(t, 1) for t in self.batch_ms]
        if self.engine is not None:
            seg = sfm_outputs.best_segment(self.engine)
            m = seg.map
            # Per keyframe the update's own RMS (the newest keyframes) when it is of this segment.
            rms = self._last.reprojection_rms_px if not full_rms and self._last is not None \
                and seg is self.engine.current else m.reprojection_rms_px(
                    self.engine.K, None if full_rms else set(sorted(m.keyframes)[-3:]))
            out.update(keyframes_registered=len(m.keyframes), landmarks=m.landmark_count(),
                       segments=len(self.engine.segments),
                       target_vertices=m.vertex_count(),
                       reprojection_rms_px=rms,
                       keyframes_registered_all=sum(len(s.map.keyframes)
                                                    for s in self.engine.segments))
        return out


def main(args: list[str] | None = None) -> None:
    common.run_node(SfmNode, args, threads=2)
