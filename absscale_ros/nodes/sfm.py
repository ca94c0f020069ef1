"""
sfm: an unscaled incremental reconstruction from the keyframes (``core/sfm.py``).

Subscribes ``/absscale/keyframes`` (Image), ``/absscale/keyframe_vertices`` (PointCloud2) and,
with ``use_tracked_steps``, ``/absscale/keyframe_motion`` (TransformStamped: the selector's
tracked step, against which a registration is checked), paired by stamp, and
``/absscale/camera_info``. After each keyframe publishes, for the segment
worth scaling (``core/sfm_outputs.best_segment``): ``/absscale/sparse_cloud`` (x y z rgb, SfM
units), ``/absscale/keyframe_path`` (nav_msgs/Path, T_world_cam per keyframe),
``/absscale/target_points`` (x y z object_id vertex_id n_obs angle_deg target_type: the
vertex landmarks seen under at least ``vertices.publish_min_angle_deg``) and
``/diagnostics``. A keyframe's features are detected on a worker thread as soon as its image
arrives. Live (``qos: sensor_data``) the map is updated on a worker thread and keyframes do
not queue (``core/sfm_live.py``; ``keyframes_skipped`` counts those replaced while waiting).
Offline, the replay's end (``/absscale/end_of_bag``) runs the final batch adjustment
(``adjust_at_end``) and publishes the converged map once more, stamped with the end's stamp,
so the scale node's last estimate is of the map that ``bench sfm`` scores.
Parameters: the scalars of ``SfmConfig`` and its stages as ``features.*``, ``twoview.*``,
``graph.*``, ``vertices.*``, ``local_map.*``, ``cloud.*`` (which landmarks are published),
``qos`` (``reliable``, or ``sensor_data`` live).
"""
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor, wait
from dataclasses import fields, is_dataclass, replace
import time
from typing import Any

from absscale_ros import conversions
from absscale_ros.core import errors, keyframes, replay, sfm, sfm_live, sfm_outputs, sfm_session
from absscale_ros.nodes import common, sfm_inputs
from nav_msgs.msg import Path
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from std_msgs.msg import Header

Item = sfm_inputs.Item  # keyframe, its vertices, its tracked step (or None)


class SfmNode(Node):

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('sfm', **kwargs)
        cfg = sfm.SfmConfig()
        flat = {f.name: getattr(cfg, f.name) for f in fields(cfg)
                if not is_dataclass(getattr(cfg, f.name))}
        values = {k: self.declare_parameter(k, v).value for k, v in flat.items()}
        values.update({field: common.declare_config(self, getattr(cfg, field), prefix)
                       for prefix, field in sfm.PARAM_PREFIXES.items()})
        p = {x.name: x.value for x in self.declare_parameters('', [
            ('pair_depth', 10), ('seed', 0), ('frame_id', 'map'), ('use_tracked_steps', True),
            ('qos', 'reliable'), ('queue_keyframes', 0), ('queue_worker', True),
            ('adjust_at_end', True)])}
        self.session = sfm_session.SfmSession(replace(cfg, **values), p['seed'], time.perf_counter)
        self._frame, self._camera = p['frame_id'], None
        self._pubs = {name: self.create_publisher(cls, f'/absscale/{name}', common.RELIABLE)
                      for name, cls in (('sparse_cloud', PointCloud2),
                                        ('keyframe_path', Path),
                                        ('target_points', PointCloud2))}
        self._diag = common.DiagnosticsPublisher(self, 'reconstruction')
        group = MutuallyExclusiveCallbackGroup()  # the map is updated by one callback at a time
        self.create_subscription(CameraInfo, '/absscale/camera_info', self._on_info,
                                 common.RELIABLE, callback_group=group)
        self._detector = ThreadPoolExecutor(1, 'sfm_features')
        self._prefetch = sfm_live.FeaturePrefetch(self._detector.submit, 2 * p['pair_depth'] + 2)
        self._updater = ThreadPoolExecutor(1, 'sfm_update') if p['qos'] == common.LIVE else None
        # Offline, queued: keyframes are acknowledged as they are queued (outputs DEFERRED) and
        # added in order on a worker, so a lossless replay feeds the nodes before the sfm (in
        # another process) meanwhile; at most ``queue_keyframes`` wait (then the callback waits
        # for the oldest). Each is acknowledged again with its outputs once published, and the
        # replay has drained only when their subscribers acknowledged those too.
        # Without ``queue_worker`` (the runner's one process) they are mapped on the executor's
        # thread instead, each once its features are detected (``sfm_inputs.ExecutorQueue``).
        self._queued: deque['Future[list[str]]'] = deque()
        self._queue_depth = p['queue_keyframes'] if self._updater is None else 0
        queued = self._queue_depth > 0
        self._queue = ThreadPoolExecutor(1, 'sfm_queue') if queued and p['queue_worker'] \
            else None
        self._on_main = sfm_inputs.ExecutorQueue(self, group) \
            if queued and not p['queue_worker'] else None
        self.live: sfm_live.LiveUpdates[Item] | None = None if self._updater is None else \
            sfm_live.LiveUpdates(self._updater.submit, time.monotonic_ns,
                                 lambda item: self._process(*item), self.session.adjust_if_due,
                                 self._skip, self.get_logger().error)
        at_end = self.live is None and p['adjust_at_end']
        self._end_ack = common.StepAck(self) if at_end else None
        self._end_sub = self.create_subscription(
            Header, common.END_OF_BAG_TOPIC, self._on_end, common.RELIABLE,
            callback_group=group) if at_end else None
        self._inputs = sfm_inputs.KeyframeInputs(self, group, p['pair_depth'],
                                                 p['use_tracked_steps'], self._on_image,
                                                 self._handle, self.session.count)

    def _on_info(self, msg: CameraInfo) -> None:
        if self.session.engine is not None:
            # The map's camera is fixed once it exists (the first keyframe's). The subscription
            # stays: destroying it from its own callback made --processes runs lose the
            # end-of-bag map's messages now and then (test_run_end_to_end).
            return
        try:
            self._camera = conversions.camera_info_to_model(msg)
        except errors.AbsScaleError as err:
            self.get_logger().warning(f'bad camera_info: {err}', throttle_duration_sec=5.0)

    def destroy_node(self) -> None:
        for worker in (self._updater, self._queue):
            if worker is not None:
                worker.shutdown(wait=True, cancel_futures=True)
        self._detector.shutdown(wait=False, cancel_futures=True)
        super().destroy_node()

    def _on_image(self, stamp_ns: int, msg: Image) -> None:
        """A keyframe's image: its latency starts; its features are detected ahead."""
        if self.live is not None:
            self.live.arrived(stamp_ns)
        if self.session.engine is not None:  # the first keyframe makes the engine (camera) first
            try:
                self._prefetch.start(stamp_ns, conversions.image_msg_to_bgr(msg),
                                     self.session.engine)
            except errors.AbsScaleError:
                pass  # _process says why

    def _handle(self, item: Item) -> list[str] | None:
        """A paired keyframe: queued (DEFERRED), processed now (its outputs), or handed to the
        live worker (None)."""
        if self._queue is not None or self._on_main is not None:
            while self._queued and (self._queued[0].done() or
                                    len(self._queued) >= self._queue_depth):
                self._result(self._queued.popleft())  # an update's exception is raised here
            self._queued.append(
                self._queue.submit(self._process_queued, item) if self._queue is not None else
                self._on_main.submit(self._prefetch.pending(conversions.stamp_to_ns(
                    item[0].header.stamp)), self._process_queued, item))
            return [replay.DEFERRED]  # taken: the replay goes on, and waits for it at the end
        if self.live is None:
            return self._process(*item)
        self.live.offer(conversions.stamp_to_ns(item[0].header.stamp), item)
        return None

    def _result(self, queued: 'Future[list[str]]') -> list[str]:
        """A queued keyframe's outputs, once it is mapped (on this thread, if queued here)."""
        if self._on_main is not None:
            self._on_main.run_through(queued)
        return queued.result()

    def _process_queued(self, item: Item) -> list[str]:
        """Queued (on the worker, or on the executor's thread without ``queue_worker``): map
        one keyframe, then acknowledge what it published."""
        outputs: list[str] = []
        try:
            outputs = self._process(*item)
        finally:  # an update that raised is re-raised in _handle; the replay need not wait
            self._inputs.ack_deferred(item[0].header.stamp, outputs)
        return outputs

    def _skip(self, stamp_ns: int, item: Item) -> keyframes.TrackedStep | None:
        """Live: a keyframe the map will not see; its step, to chain."""
        self._prefetch.cancel(stamp_ns)
        try:
            return conversions.tracked_step_from_msg(item[2]) if item[2] else None
        except errors.AbsScaleError:
            return None

    def _process(self, image_msg: Image, vertices_msg: PointCloud2, motion_msg: Any) -> list[str]:
        stamp_ns = conversions.stamp_to_ns(image_msg.header.stamp)
        image, features = self._prefetch.take(stamp_ns)
        try:
            image = conversions.image_msg_to_bgr(image_msg) if image is None else image
            rows = conversions.cloud_msg_to_array(vertices_msg)
            step = conversions.tracked_step_from_msg(motion_msg) if motion_msg else None
        except errors.AbsScaleError as err:
            self.get_logger().warning(f'keyframe dropped: {err}', throttle_duration_sec=5.0)
            return []
        if self.live is not None:
            step = self.live.bridge(stamp_ns, step)
        self.session.add(stamp_ns, image, sfm_outputs.vertices_from_rows(rows), step, features,
                         self._camera, defer_batch=self.live is not None)
        return self._publish_map(stamp_ns)

    def _on_end(self, msg: Header) -> None:
        """Offline, the bag's end: the final batch adjustment, then the map once more."""
        outputs: list[str] = []
        try:
            while self._queued:
                self._result(self._queued.popleft())  # the queued keyframes first
            if self.session.finish() is not None:
                outputs = self._publish_map(conversions.stamp_to_ns(msg.stamp))
        except Exception as err:  # noqa: BLE001 - the run must still end, not wait 300 s
            self.get_logger().error(f'final batch adjustment failed: {err}')
        finally:
            assert self._end_ack is not None and self._end_sub is not None
            self._end_ack.ack(msg.stamp, self._end_sub.topic_name, outputs)

    def _publish_map(self, stamp_ns: int) -> list[str]:
        """The map's messages and diagnostics, stamped ``stamp_ns``; the topics published."""
        msgs, vertices = sfm_inputs.map_messages(self.session, stamp_ns, self._frame)
        for name, msg in msgs.items():  # target_points last: scale reads cloud and path then
            self._pubs[name].publish(msg)
        r = self.report(full_rms=False)
        self._diag.publish(*self.session.diagnosis(r, vertices),
                           {**r, 'target_vertices': vertices}, stamp_ns)
        return [self._pubs[name].topic_name for name in msgs]

    def report(self, full_rms: bool = True) -> dict[str, Any]:
        """See ``SfmSession.report``; live, with the skipped keyframes and the timeline."""
        if full_rms:  # the final report: after the queued updates (called from outside them)
            if self._on_main is not None:
                for queued in list(self._queued):
                    self._on_main.run_through(queued)
            wait(list(self._queued))
        live = self.live
        return self.session.report(full_rms, live.skipped if live else 0, live and {
            'timeline_ns': list(live.timeline_ns),
            'batch_ms': [round(t, 1) for t in live.batch_ms]})


def main(args: list[str] | None = None) -> None:
    common.run_node(SfmNode, args, threads=2)
