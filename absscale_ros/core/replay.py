"""
Bookkeeping for replaying a bag: when each message is due, and when a stepped one is consumed.

Lossless step mode works by causal acknowledgement. After a node handles a message from a
stepped topic it acknowledges (node, input topic, stamp) and names the topics it published
for that stamp; every acking subscriber of those topics then owes an acknowledgement too.
The step is complete when nothing is owed, i.e. the whole graph has drained that frame.

A node that queues its work (the sfm with ``queue_keyframes``) names ``DEFERRED`` among its
outputs: it then owes a second acknowledgement (node, ``DEFERRED``, stamp) naming what it
published once it did. A step that owes nothing else no longer holds a place in the window
(the replay goes on), but the replay is not drained until it completes.
"""
from dataclasses import dataclass, field
from typing import Callable, Iterable

# An output that is no topic: the acknowledging node acknowledges this stamp again later.
DEFERRED = 'deferred'


@dataclass(frozen=True)
class Ack:
    """One acknowledgement: ``node`` handled ``input_topic`` at ``stamp_ns``."""

    node: str
    input_topic: str
    stamp_ns: int
    outputs: tuple[str, ...] = ()

    def encode(self) -> str:
        return f'{self.node}|{self.input_topic}|{",".join(self.outputs)}'

    @staticmethod
    def decode(text: str, stamp_ns: int) -> 'Ack':
        parts = text.split('|')
        if len(parts) != 3 or not parts[0] or not parts[1]:
            raise ValueError(f'malformed ack {text!r}: want node|input_topic|outputs')
        outputs = tuple(o for o in parts[2].split(',') if o)
        return Ack(parts[0], parts[1], stamp_ns, outputs)


@dataclass
class StepTracker:
    """
    What the graph still owes for the message in flight.

    Owed and received acknowledgements are sets of (node, input topic): a topic announced
    twice for one stamp (a node that consumes two inputs and names its outputs in both
    acknowledgements) is still one message to wait for, and an acknowledgement that overtakes
    its announcement is simply already received.

    :param consumers_of: topic -> names of the acknowledging nodes subscribed to it.
    """

    consumers_of: Callable[[str], Iterable[str]]
    stamp_ns: int | None = None
    owed: set[tuple[str, str]] = field(default_factory=set)
    _received: set[tuple[str, str]] = field(default_factory=set)

    def start(self, topic: str, stamp_ns: int) -> None:
        """A stepped message on ``topic`` stamped ``stamp_ns`` has just been published."""
        self.stamp_ns = stamp_ns
        self.owed.clear()
        self._received.clear()
        self._expect(topic)

    def _expect(self, topic: str, producer: str = '') -> None:
        for node in [producer] if topic == DEFERRED else self.consumers_of(topic):
            if (node, topic) not in self._received:
                self.owed.add((node, topic))

    def on_ack(self, ack: Ack) -> bool:
        """Record ``ack``; return True if it belonged to the message in flight."""
        if self.stamp_ns is None or ack.stamp_ns != self.stamp_ns:
            return False  # stale: from a step that timed out
        key = (ack.node, ack.input_topic)
        self._received.add(key)
        self.owed.discard(key)
        for topic in ack.outputs:
            self._expect(topic, ack.node)
        return True

    @property
    def done(self) -> bool:
        return self.stamp_ns is None or not self.owed

    @property
    def deferred(self) -> bool:
        """Only deferred acknowledgements are owed (queued work; see ``DEFERRED``)."""
        return bool(self.owed) and all(topic == DEFERRED for _, topic in self.owed)

    def pending(self) -> list[str]:
        return sorted(f'{n} on {t}' for n, t in self.owed)


def due_wall_ns(bag_t_ns: int, bag_t0_ns: int, wall_t0_ns: int, rate: float) -> int:
    """Wall-clock time at which a message logged at ``bag_t_ns`` is due at replay ``rate``."""
    if rate <= 0.0:
        raise ValueError(f'rate must be positive, got {rate}')
    return wall_t0_ns + int((bag_t_ns - bag_t0_ns) / rate)


class StepWindow:
    """
    Up to ``size`` stepped messages in flight at once, each with its own ``StepTracker``.

    A window of 1 is strict lock-step; a larger one lets the stages of the graph work on
    different frames at the same time (the detector on frame k+1 while the SfM is busy with
    keyframe k) while staying lossless: no more than ``size`` frames are ever queued, apart
    from those a node queued itself and acknowledged as ``DEFERRED`` (its queue bounds them).
    Started-at times come from the caller (core reads no clock).

    :param consumers_of: topic -> names of the acknowledging nodes subscribed to it.
    """

    def __init__(self, consumers_of: Callable[[str], Iterable[str]], size: int = 1) -> None:
        if size < 1:
            raise ValueError(f'step window must be >= 1, got {size}')
        self.size = size
        self._consumers_of = consumers_of
        self._open: dict[int, tuple[StepTracker, float]] = {}
        # Steps that owe only what a node queued: out of the window, still to drain.
        self._deferred: dict[int, tuple[StepTracker, float]] = {}
        self.deferred_total = 0  # steps that were ever deferred

    def start(self, topic: str, stamp_ns: int, now: float) -> None:
        """A stepped message on ``topic`` stamped ``stamp_ns`` went out at ``now``."""
        tracker = StepTracker(self._consumers_of)
        tracker.start(topic, stamp_ns)
        if not tracker.done:
            self._open[stamp_ns] = (tracker, now)

    def on_ack(self, ack: Ack, now: float) -> bool:
        """Record ``ack`` (received at ``now``); return True if it freed a place in the window
        (its step completed, or owes only deferred acknowledgements) or completed a deferred
        step."""
        for steps in (self._open, self._deferred):
            entry = steps.get(ack.stamp_ns)
            if entry is not None:
                break
        else:
            return False
        tracker = entry[0]
        if not tracker.on_ack(ack):
            return False
        if tracker.done:
            del steps[ack.stamp_ns]
            if steps is self._deferred:
                # A queue is worked in order: the steps queued behind this one waited for it,
                # so their time counts from now (not from when they were queued).
                self._deferred = {s: (t, max(at, now)) for s, (t, at) in self._deferred.items()}
            return True
        if steps is self._open and tracker.deferred:
            del self._open[ack.stamp_ns]
            self._deferred[ack.stamp_ns] = (tracker, now)  # its timeout counts from now
            self.deferred_total += 1
            return True
        return False

    @property
    def full(self) -> bool:
        return len(self._open) >= self.size

    @property
    def empty(self) -> bool:
        """No step in flight, deferred ones included."""
        return not self._open and not self._deferred

    def expire(self, now: float, timeout_s: float) -> list[tuple[int, list[str]]]:
        """Give up on steps open (or deferred) longer than ``timeout_s``; return (stamp, what
        was owed)."""
        out = []
        for steps in (self._open, self._deferred):
            late = [s for s, (_, t) in steps.items() if now - t >= timeout_s]
            out += [(s, steps.pop(s)[0].pending()) for s in late]
        return out
