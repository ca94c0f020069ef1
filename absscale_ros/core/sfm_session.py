"""
The sfm node's map, without ROS: makes the ``IncrementalSfm`` on the first keyframe, adds
keyframes with their bookkeeping (statuses, update times, the stamps the map was given) and
assembles the report and the diagnostics. Thread-safe: a live update worker changes the map
while a report may be taken from another thread (the node's end).
"""
from concurrent.futures import Future
import threading
from typing import Any, Callable

from absscale_ros.core import keyframe_geometry, keyframes, sfm, sfm_outputs
from absscale_ros.core import vertex_matching as vm
from absscale_ros.core.types import CameraModel
import numpy as np
import numpy.typing as npt


class SfmSession:
    """
    One node's incremental map and what it reports.

    :param cfg: the SfM settings.
    :param seed: seeds the engine's RANSAC.
    :param clock_s: a monotonic clock, s (the update times).
    """

    def __init__(self, cfg: sfm.SfmConfig, seed: int, clock_s: Callable[[], float]) -> None:
        self.cfg, self._seed, self._clock_s = cfg, seed, clock_s
        self.engine: sfm.IncrementalSfm | None = None
        self.last: sfm.UpdateResult | None = None
        self.statuses: dict[str, int] = {}
        self.times_ms: list[float] = []
        # Stamps of the keyframes the map was given (live: those not skipped), in order: the
        # core run over them offline replays what this map saw (`bench sfm --keyframes-from`).
        self.keyframe_stamps_ns: list[int] = []
        # ... and the tracked step each came with (None: none), so the replay checks its poses
        # against the same motion the live map did.
        self.keyframe_steps: list[dict[str, Any] | None] = []
        self.features_prefetched = 0  # keyframes whose features came from the worker
        self.final_batch_ms: float | None = None  # ``finish``, once run
        # Re-entrant: held while the map changes, so a report from another thread reads it whole.
        self._lock = threading.RLock()

    def count(self, status: str) -> None:
        """Count a keyframe's fate (an update's status, or why it never reached the map)."""
        self.statuses[status] = self.statuses.get(status, 0) + 1

    def add(self, stamp_ns: int, image: npt.NDArray[np.uint8], vertices: vm.Vertices,
            step: keyframes.TrackedStep | None, features: 'Future[Any] | None',
            camera: CameraModel | None, defer_batch: bool) -> sfm.UpdateResult:
        """
        Add one keyframe; the first makes the engine.

        :param image: (H, W, 3) uint8 BGR.
        :param features: the features detected ahead (``FeaturePrefetch``), or None.
        :param camera: the calibration, used if it has the image's size (else a nominal one).
        """
        with self._lock:
            if self.engine is None:
                h, w = image.shape[:2]
                if camera is None or (camera.width, camera.height) != (w, h):
                    camera = keyframe_geometry.nominal_camera(w, h)
                self.engine = sfm.IncrementalSfm(camera, self.cfg,
                                                 np.random.default_rng(self._seed))
            t0 = self._clock_s()  # waiting for the prefetched features counts
            self.last = self.engine.add_keyframe(
                stamp_ns, image, vertices, step,
                features.result() if features is not None else None, defer_batch=defer_batch)
            self.features_prefetched += features is not None
            sfm_outputs.compact(self.engine)  # finished segments to arrays: memory of long scans
            self.times_ms.append(1e3 * (self._clock_s() - t0))
            self.keyframe_stamps_ns.append(stamp_ns)
            self.keyframe_steps.append(None if step is None else {
                'ref_stamp_ns': int(step.ref_stamp_ns),
                'rotation': [float(v) for v in np.ravel(step.rotation)],
                'centre': [float(v) for v in np.ravel(step.centre)]})
            self.count(self.last.status)
            return self.last

    def finish(self) -> sfm.UpdateResult | None:
        """
        The final batch adjustment of every segment, to convergence (an offline run's end:
        without it the map is as far as the last periodic batch got); None: no map.
        """
        with self._lock:
            if self.engine is None:
                return None
            t0 = self._clock_s()
            self.last = self.engine.finish()
            self.final_batch_ms = 1e3 * (self._clock_s() - t0)
            return self.last

    def adjust_if_due(self, stop: Callable[[], bool] | None = None) -> bool:
        """Run the batch adjustment that deferred updates left out, if due; whether it ran.
        ``stop``: asked between its steps whether to pause it (a keyframe waits)."""
        with self._lock:
            return self.engine is not None and self.engine.adjust_if_due(stop) is not None

    def report(self, full_rms: bool = True, skipped: int = 0,
               live: dict[str, Any] | None = None) -> dict[str, Any]:
        """
        Keyframes, segments, reprojection and update times, for report.json.

        :param full_rms: RMS over the whole published segment, with the per-keyframe lists
            (else over its newest three keyframes: cheap enough for every keyframe).
        :param skipped: keyframes a live map skipped.
        :param live: a live run's lists, added with ``full_rms``.
        """
        with self._lock:
            return self._report(full_rms, skipped, live)

    def _report(self, full_rms: bool, skipped: int,
                live: dict[str, Any] | None) -> dict[str, Any]:
        times = np.array(self.times_ms or [np.nan])
        out: dict[str, Any] = {'keyframes_in': len(self.times_ms), 'keyframes_registered': 0,
                               'keyframes_skipped': skipped,
                               'segments': 0, 'landmarks': 0, 'target_vertices': 0,
                               'reprojection_rms_px': float('nan'),
                               'update_ms_median': float(np.median(times)),
                               'update_ms_p95': float(np.percentile(times, 95)),
                               'statuses': dict(self.statuses)}
        if self.final_batch_ms is not None:
            out['final_batch_ms'] = round(self.final_batch_ms, 1)
        if full_rms:  # the whole run (not in every keyframe's diagnostics)
            out['update_ms'] = [round(t, 1) for t in self.times_ms]
            out['keyframe_stamps_ns'] = list(self.keyframe_stamps_ns)
            out['keyframe_steps'] = list(self.keyframe_steps)
            out.update(live or {})
        if self.engine is not None:
            seg = sfm_outputs.best_segment(self.engine)
            m = seg.map
            # Per keyframe the update's own RMS (the newest keyframes) when it is of this segment.
            rms = self.last.reprojection_rms_px if not full_rms and self.last is not None \
                and seg is self.engine.current else m.reprojection_rms_px(
                    self.engine.K, None if full_rms else set(sorted(m.keyframes)[-3:]))
            out.update(keyframes_registered=len(m.keyframes), landmarks=m.landmark_count(),
                       segments=len(self.engine.segments),
                       target_vertices=m.vertex_count(),
                       reprojection_rms_px=rms,
                       keyframes_registered_all=sum(len(s.map.keyframes)
                                                    for s in self.engine.segments))
        return out

    def diagnosis(self, report: dict[str, Any], vertices: int) -> tuple[str, str]:
        """
        The diagnostics level ('ok' or 'warn') and text after a keyframe.

        :param report: ``report(full_rms=False)``.
        :param vertices: target vertices published.
        """
        level, text = 'ok', self.last.message if self.last else 'no keyframe yet'
        if report['keyframes_registered'] == 0:
            level, text = 'warn', f'no reconstruction yet (camera only rotating?): {text}'
        elif vertices == 0:
            level, text = 'warn', ('no target vertex reconstructed yet (target not seen from '
                                   f'two keyframes with parallax); {text}')
        return level, text
