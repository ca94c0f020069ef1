"""
Bookkeeping for replaying a bag: when each message is due, and when a stepped one is consumed.

Lossless step mode works by causal acknowledgement. After a node handles a message from a
stepped topic it acknowledges (node, input topic, stamp) and names the topics it published
for that stamp; every acking subscriber of those topics then owes an acknowledgement too.
The step is complete when nothing is owed, i.e. the whole graph has drained that frame.
"""
from collections import Counter
from dataclasses import dataclass, field
from typing import Callable, Iterable


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

    :param consumers_of: topic -> names of the acknowledging nodes subscribed to it.
    """

    consumers_of: Callable[[str], Iterable[str]]
    stamp_ns: int | None = None
    owed: Counter[tuple[str, str]] = field(default_factory=Counter)
    _early: Counter[tuple[str, str]] = field(default_factory=Counter)

    def start(self, topic: str, stamp_ns: int) -> None:
        """A stepped message on ``topic`` stamped ``stamp_ns`` has just been published."""
        self.stamp_ns = stamp_ns
        self.owed.clear()
        self._early.clear()
        self._expect(topic)

    def _expect(self, topic: str) -> None:
        for node in self.consumers_of(topic):
            key = (node, topic)
            if self._early[key] > 0:  # its ack overtook the one that announced it
                self._early[key] -= 1
            else:
                self.owed[key] += 1

    def on_ack(self, ack: Ack) -> bool:
        """Record ``ack``; return True if it belonged to the message in flight."""
        if self.stamp_ns is None or ack.stamp_ns != self.stamp_ns:
            return False  # stale: from a step that timed out
        key = (ack.node, ack.input_topic)
        if self.owed[key] > 0:
            self.owed[key] -= 1
        else:
            self._early[key] += 1
        for topic in ack.outputs:
            self._expect(topic)
        return True

    @property
    def done(self) -> bool:
        return self.stamp_ns is None or sum(self.owed.values()) == 0

    def pending(self) -> list[str]:
        return sorted(f'{n} on {t}' for (n, t), c in self.owed.items() if c > 0)


def due_wall_ns(bag_t_ns: int, bag_t0_ns: int, wall_t0_ns: int, rate: float) -> int:
    """Wall-clock time at which a message logged at ``bag_t_ns`` is due at replay ``rate``."""
    if rate <= 0.0:
        raise ValueError(f'rate must be positive, got {rate}')
    return wall_t0_ns + int((bag_t_ns - bag_t0_ns) / rate)
