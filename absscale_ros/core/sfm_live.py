"""
The sfm node's worker-thread bookkeeping, without ROS: features detected ahead, and live
updates that never queue.

Live, a keyframe that arrives while another still waits for the map replaces it: the waiting
one is skipped, and its tracked step is kept so the next keyframe the map takes has a step
from the last keyframe the map saw (the skipped steps chained). The periodic batch
adjustment runs once no keyframe waits, and pauses for one that comes meanwhile. Threads
and clocks come in as callables (an executor's ``submit``, ``time.monotonic_ns``), so tests
drive this deterministically.
"""
from concurrent.futures import Future
import threading
from typing import Any, Callable, Generic, TypeVar

from absscale_ros.core import keyframes
import numpy as np
import numpy.typing as npt

T = TypeVar('T')
Step = keyframes.TrackedStep | None


class FeaturePrefetch:
    """
    Keyframe features detected on a worker as soon as the image is there (OpenCV releases the
    GIL), while its vertices are still on their way. Thread-safe.

    :param submit: runs ``fn(image)`` on the worker, returning its future.
    :param keep: at most this many pending (older ones were never paired: cancelled).
    """

    def __init__(self, submit: Callable[..., 'Future[Any]'], keep: int) -> None:
        self._submit, self._keep = submit, keep
        self._lock = threading.Lock()
        self._pending: dict[int, tuple[npt.NDArray[np.uint8], 'Future[Any]']] = {}

    def start(self, stamp_ns: int, image: npt.NDArray[np.uint8], engine: Any) -> None:
        """Detect ``engine.detect(image)`` ahead, if the image has the engine camera's size."""
        if image.shape[:2] != (engine.camera.height, engine.camera.width):
            return  # the update says why it fails
        with self._lock:
            self._pending[stamp_ns] = (image, self._submit(engine.detect, image))
            while len(self._pending) > self._keep:
                self._pending.pop(min(self._pending))[1].cancel()

    def pending(self, stamp_ns: int) -> 'Future[Any] | None':
        """The features' future of a prefetched keyframe (left in place), or None."""
        with self._lock:
            return self._pending.get(stamp_ns, (None, None))[1]

    def take(self, stamp_ns: int) -> tuple[Any, 'Future[Any] | None']:
        """The decoded image and its features' future, or (None, None) if not prefetched."""
        with self._lock:
            return self._pending.pop(stamp_ns, (None, None))

    def cancel(self, stamp_ns: int) -> None:
        """Not needed (its keyframe was skipped): not detected unless already started."""
        entry = self.take(stamp_ns)[1]
        if entry is not None:
            entry.cancel()


class LiveUpdates(Generic[T]):
    """
    Live map updates: at most one keyframe waits; the newest is taken.

    :param submit: runs the update loop on the (single) update worker.
    :param clock_ns: monotonic clock, ns (one clock for all processes: the latency timeline).
    :param process: adds a keyframe to the map and publishes it.
    :param adjust: runs the batch adjustment the updates deferred, if due; whether it ran. It
        is given a callable saying whether a keyframe now waits, to pause the adjustment.
    :param skip: releases a keyframe replaced while waiting; returns its tracked step.
    :param on_error: logs an exception of ``process`` or ``adjust`` (a worker's would vanish).
    """

    def __init__(self, submit: Callable[[Callable[[], None]], Any], clock_ns: Callable[[], int],
                 process: Callable[[T], None], adjust: Callable[[Callable[[], bool]], bool],
                 skip: Callable[[int, T], Step], on_error: Callable[[str], None]) -> None:
        self._submit, self._clock_ns = submit, clock_ns
        self._process, self._adjust, self._skip, self._on_error = process, adjust, skip, on_error
        self._lock = threading.Lock()
        self._waiting: tuple[int, T] | None = None
        self.busy = False  # the update loop is running
        self._skipped_steps: dict[int, Step] = {}
        self.skipped = 0
        self._arrived_ns: dict[int, int] = {}
        # Per keyframe added: stamp, and when its image arrived, its update started and ended.
        self.timeline_ns: list[tuple[int, int, int, int]] = []
        self.batch_ms: list[float] = []  # the deferred batch adjustments' steps

    def arrived(self, stamp_ns: int) -> None:
        """A keyframe's image came (the start of its latency)."""
        with self._lock:
            self._arrived_ns[stamp_ns] = self._clock_ns()

    def offer(self, stamp_ns: int, item: T) -> None:
        """Hand a keyframe to the update worker; one still waiting is skipped."""
        with self._lock:
            stale, self._waiting = self._waiting, (stamp_ns, item)
            if stale is not None:
                self.skipped += 1
                self._skipped_steps[stale[0]] = self._skip(*stale)
            if self.busy:
                return
            self.busy = True
        self._submit(self._loop)

    def bridge(self, stamp_ns: int, step: Step) -> Step:
        """The step to keyframe ``stamp_ns`` from the last one the map saw, over skipped ones."""
        with self._lock:
            while step is not None and step.ref_stamp_ns in self._skipped_steps:
                earlier = self._skipped_steps.pop(step.ref_stamp_ns)
                step = None if earlier is None else keyframes.chain(earlier, step)
            for old in [s for s in self._skipped_steps if s < stamp_ns]:
                del self._skipped_steps[old]
        return step

    def _loop(self) -> None:
        """
        Add the waiting keyframe to the map until none waits; then the batch adjustment its
        update left out, if due (it pauses for a keyframe that comes meanwhile and goes on
        after it), and look again.
        """
        while True:
            with self._lock:
                item, self._waiting = self._waiting, None
            if item is None:
                if self._adjust_if_due():
                    continue
                with self._lock:
                    if self._waiting is None:
                        self.busy = False
                        return
                continue
            started = self._clock_ns()
            try:
                self._process(item[1])
                with self._lock:
                    arrived = self._arrived_ns.pop(item[0], started)
                    for old in [s for s in self._arrived_ns if s < item[0]]:
                        del self._arrived_ns[old]
                self.timeline_ns.append((item[0], arrived, started, self._clock_ns()))
            except Exception as err:  # noqa: BLE001 (a worker's exception would vanish)
                self._on_error(f'keyframe update failed: {err!r}')

    def _adjust_if_due(self) -> bool:
        t0 = self._clock_ns()
        try:
            ran = self._adjust(lambda: self._waiting is not None)
        except Exception as err:  # noqa: BLE001 (a worker's exception would vanish)
            self._on_error(f'batch adjustment failed: {err!r}')
            return False
        if ran:
            self.batch_ms.append(1e-6 * (self._clock_ns() - t0))
        return ran
