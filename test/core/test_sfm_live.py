"""The sfm node's worker bookkeeping without ROS: newest keyframe first, steps chained."""
from concurrent.futures import ThreadPoolExecutor
import itertools
import threading
import time

from absscale_ros.core import keyframes, sfm_live
import numpy as np
from scipy.spatial.transform import Rotation

STAMPS = [(k + 1) * 100 for k in range(6)]


def _poses(count: int) -> list[np.ndarray]:
    """T_world_cam of a camera turning and moving along a curve."""
    out = []
    for k in range(count):
        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler('xyz', [0.02 * k, 0.1 * k, -0.03 * k]).as_matrix()
        T[:3, 3] = [0.3 * k, 0.05 * k * k, -0.1 * k]
        out.append(T)
    return out


def _step(T: list[np.ndarray], k: int) -> keyframes.TrackedStep | None:
    """The true step to keyframe ``k`` from the one before, as the selector tracks it."""
    if k == 0:
        return None
    rel = np.linalg.inv(T[k - 1]) @ T[k]
    return keyframes.TrackedStep(STAMPS[k - 1], rel[:3, :3].T, rel[:3, 3])


class Harness:
    """A LiveUpdates on a real single worker whose first update holds until released."""

    def __init__(self, adjust=lambda stop: False) -> None:
        self.release, self.processed, self.skipped, self.errors = threading.Event(), [], [], []
        ticks = itertools.count(1000)
        self.pool = ThreadPoolExecutor(1)
        self.live = sfm_live.LiveUpdates(self.pool.submit, lambda: next(ticks), self._process,
                                         adjust, self._skip, self.errors.append)

    def _process(self, item) -> None:
        stamp_ns, step = item
        self.release.wait(timeout=10.0)
        if step == 'boom':
            raise RuntimeError('boom')
        self.processed.append((stamp_ns, self.live.bridge(stamp_ns, step)))

    def _skip(self, stamp_ns, item):
        self.skipped.append(stamp_ns)
        return item[1]

    def idle(self) -> bool:
        deadline = time.monotonic() + 10.0
        while self.live.busy and time.monotonic() < deadline:
            time.sleep(0.01)
        self.pool.shutdown(wait=True)
        return not self.live.busy


def test_a_busy_worker_takes_the_newest_keyframe_and_chains_the_skipped_steps() -> None:
    T, h = _poses(6), Harness()
    for k, stamp in enumerate(STAMPS):
        h.live.arrived(stamp)
        h.live.offer(stamp, (stamp, _step(T, k)))
        if k == 0:  # the worker has taken keyframe 0 and holds: 1-4 each wait and are replaced
            while h.live._waiting is not None:
                time.sleep(0.01)
    h.release.set()
    assert h.idle() and not h.errors
    assert [s for s, _ in h.processed] == [STAMPS[0], STAMPS[-1]]
    assert h.skipped == STAMPS[1:-1] and h.live.skipped == 4
    step = h.processed[1][1]  # from keyframe 0, over the four skipped
    rel = np.linalg.inv(T[0]) @ T[-1]
    assert step.ref_stamp_ns == STAMPS[0]
    assert np.allclose(step.rotation, rel[:3, :3].T) and np.allclose(step.centre, rel[:3, 3])
    # Latency: each added keyframe's image arrived before its update started and ended.
    assert [t[0] for t in h.live.timeline_ns] == [STAMPS[0], STAMPS[-1]]
    assert all(a < s < e for _, a, s, e in h.live.timeline_ns)
    assert h.live._skipped_steps == {} and h.live._arrived_ns == {}  # nothing left to grow


def test_a_skipped_keyframe_without_a_step_leaves_the_next_unchecked() -> None:
    live = sfm_live.LiveUpdates(lambda fn: None, lambda: 0, lambda item: None, lambda: False,
                                lambda stamp, item: item, lambda text: None)
    live.offer(STAMPS[1], None)  # keyframe 1 came without a tracked step
    live.offer(STAMPS[2], None)  # replaces it (nothing runs the loop here): skipped
    assert live.skipped == 1
    assert live.bridge(STAMPS[2], keyframes.TrackedStep(STAMPS[1], np.eye(3), np.ones(3))) \
        is None  # its step starts at a keyframe skipped without a step of its own
    seen = keyframes.TrackedStep(STAMPS[0], np.eye(3), np.ones(3))
    assert live.bridge(STAMPS[3], seen) is seen  # from a keyframe the map saw: as it is


def test_the_deferred_adjustment_runs_once_idle_and_failures_are_reported() -> None:
    due = [True, False]
    h = Harness(adjust=lambda stop: due.pop(0) if due else False)
    h.release.set()
    h.live.offer(STAMPS[0], (STAMPS[0], 'boom'))
    assert h.idle()
    assert h.errors == ["keyframe update failed: RuntimeError('boom')"]
    assert h.live.timeline_ns == [] and len(h.live.batch_ms) == 1 and due == []

    def broken(stop) -> bool:
        raise ValueError('singular')

    h = Harness(adjust=broken)
    h.release.set()
    h.live.offer(STAMPS[0], (STAMPS[0], None))
    assert h.idle() and h.errors == ["batch adjustment failed: ValueError('singular')"]
    assert [s for s, _ in h.processed] == [STAMPS[0]] and h.live.batch_ms == []


class Engine:
    """What FeaturePrefetch needs of an IncrementalSfm: the camera's size and detect."""

    class camera:
        width, height = 8, 6

    def __init__(self, gate: threading.Event | None = None) -> None:
        self.gate = gate

    def detect(self, image: np.ndarray) -> float:
        if self.gate is not None:
            self.gate.wait(timeout=10.0)
        return float(image.sum())


def test_features_are_detected_ahead_and_unpaired_ones_cancelled() -> None:
    gate = threading.Event()
    with ThreadPoolExecutor(1) as pool:
        prefetch = sfm_live.FeaturePrefetch(pool.submit, keep=2)
        images = [np.full((6, 8, 3), k, np.uint8) for k in range(4)]
        prefetch.start(0, np.zeros((5, 8, 3), np.uint8), Engine(gate))  # not the camera's size
        assert prefetch.take(0) == (None, None)
        for k, image in enumerate(images):
            prefetch.start(k, image, Engine(gate))  # 0 runs (held); 1 waits, then 2, 3
        assert prefetch.take(1) == (None, None)  # the oldest beyond two pending: dropped
        image, future = prefetch.take(3)
        assert image is images[3]
        _, waiting = prefetch.take(2)
        prefetch.start(2, images[2], Engine(gate))
        prefetch.cancel(2)  # skipped: its detection is not run
        gate.set()
        assert future.result(timeout=10.0) == images[3].sum() == 6 * 8 * 3 * 3
    assert prefetch.take(2) == (None, None)


def test_the_adjustment_is_told_when_a_keyframe_starts_waiting() -> None:
    told = []

    def adjust(stop) -> bool:
        if told:
            return False
        told.append(stop())  # nothing waits yet
        h.live.offer(STAMPS[1], (STAMPS[1], None))  # a keyframe arrives mid-adjustment
        told.append(stop())
        return True

    h = Harness(adjust=adjust)
    h.release.set()
    h.live.offer(STAMPS[0], (STAMPS[0], None))
    assert h.idle() and h.errors == []
    assert told == [False, True]  # so a batch can end early for it
    assert [s for s, _ in h.processed] == [STAMPS[0], STAMPS[1]]
