"""
Bounded buffers that line up messages of two streams (the message_filters equivalent).

``StampPairer`` matches items of two streams by identical stamp (a frame and its vertices);
``HoldQueue`` keeps items until a condition holds or they expire (a frame waiting for its
camera_info). Both are bounded, and both hand back what they give up on, so a node can still
acknowledge every input it drops. No clock: callers pass times in.
"""
from collections import OrderedDict, deque
from dataclasses import dataclass
from typing import Callable, Generic, TypeVar

A = TypeVar('A')
B = TypeVar('B')
T = TypeVar('T')


@dataclass(frozen=True)
class Pairing(Generic[A, B]):
    """What one ``add`` produced: matched pairs and unmatched items given up on."""

    pairs: list[tuple[int, A, B]]
    dropped_first: list[tuple[int, A]]
    dropped_second: list[tuple[int, B]]


class StampPairer(Generic[A, B]):
    """
    Pair items of two streams that carry the same stamp (int ns).

    :param depth: unmatched items kept per stream; the oldest are given up on beyond it, and
        every unmatched item older than a pair just made is given up on at once (streams are
        in stamp order, so its partner can no longer come).
    """

    def __init__(self, depth: int = 10) -> None:
        if depth < 1:
            raise ValueError(f'depth must be >= 1, got {depth}')
        self.depth = depth
        self._first: OrderedDict[int, A] = OrderedDict()
        self._second: OrderedDict[int, B] = OrderedDict()

    def add_first(self, stamp_ns: int, item: A) -> Pairing[A, B]:
        """Add an item of the first stream (for example a frame)."""
        out: Pairing[A, B] = Pairing([], [], [])
        if stamp_ns in self._second:
            out.pairs.append((stamp_ns, item, self._second.pop(stamp_ns)))
        else:
            self._push(self._first, stamp_ns, item, out.dropped_first)
        self._settle(out)
        return out

    def add_second(self, stamp_ns: int, item: B) -> Pairing[A, B]:
        """Add an item of the second stream (for example the vertices of a frame)."""
        out: Pairing[A, B] = Pairing([], [], [])
        if stamp_ns in self._first:
            out.pairs.append((stamp_ns, self._first.pop(stamp_ns), item))
        else:
            self._push(self._second, stamp_ns, item, out.dropped_second)
        self._settle(out)
        return out

    def _push(self, buf: 'OrderedDict[int, T]', stamp_ns: int, item: T,
              dropped: list[tuple[int, T]]) -> None:
        if stamp_ns in buf:  # a repeated stamp replaces the older item
            dropped.append((stamp_ns, buf.pop(stamp_ns)))
        buf[stamp_ns] = item
        while len(buf) > self.depth:
            dropped.append(buf.popitem(last=False))

    def _settle(self, out: Pairing[A, B]) -> None:
        if not out.pairs:
            return
        newest = max(s for s, _, _ in out.pairs)
        for buf, dropped in ((self._first, out.dropped_first), (self._second, out.dropped_second)):
            for stamp in [s for s in buf if s < newest]:
                dropped.append((stamp, buf.pop(stamp)))  # type: ignore[arg-type]

    def flush(self) -> tuple[list[tuple[int, A]], list[tuple[int, B]]]:
        """Give up on everything held (shutdown)."""
        first, second = list(self._first.items()), list(self._second.items())
        self._first.clear()
        self._second.clear()
        return first, second

    def __len__(self) -> int:
        return len(self._first) + len(self._second)


class HoldQueue(Generic[T]):
    """
    Items waiting for a condition, at most ``depth`` of them and each for at most ``wait_s``.

    :param depth: items held; adding one more gives up on the oldest.
    :param wait_s: an item held longer than this is given up on by ``expire``.
    """

    def __init__(self, depth: int, wait_s: float) -> None:
        if depth < 1 or wait_s < 0.0:
            raise ValueError(f'need depth >= 1 and wait_s >= 0, got {depth}, {wait_s}')
        self.depth, self.wait_s = depth, wait_s
        self._items: deque[tuple[float, T]] = deque()

    def add(self, item: T, now_s: float) -> list[T]:
        """Hold ``item`` from ``now_s``; return the items given up on to make room."""
        self._items.append((now_s, item))
        dropped = []
        while len(self._items) > self.depth:
            dropped.append(self._items.popleft()[1])
        return dropped

    def release(self, ready: Callable[[T], bool]) -> list[T]:
        """Remove and return, oldest first, the leading items for which ``ready`` is true."""
        out = []
        while self._items and ready(self._items[0][1]):
            out.append(self._items.popleft()[1])
        return out

    def expire(self, now_s: float) -> list[T]:
        """Remove and return the items held for longer than ``wait_s``."""
        out = []
        while self._items and now_s - self._items[0][0] > self.wait_s:
            out.append(self._items.popleft()[1])
        return out

    def __len__(self) -> int:
        return len(self._items)
