"""Stamp pairing and hold queues: every item comes out once, paired or given up on."""
from absscale_ros.core import pairing
import pytest


def test_pairs_by_stamp_in_either_order() -> None:
    p: pairing.StampPairer[str, str] = pairing.StampPairer(depth=3)
    assert p.add_first(1, 'f1').pairs == []
    assert p.add_second(1, 'v1').pairs == [(1, 'f1', 'v1')]
    assert p.add_second(2, 'v2').pairs == []
    assert p.add_first(2, 'f2').pairs == [(2, 'f2', 'v2')]
    assert len(p) == 0


def test_bounded_and_stale_items_are_handed_back() -> None:
    p: pairing.StampPairer[str, str] = pairing.StampPairer(depth=2)
    p.add_first(1, 'f1')
    p.add_first(2, 'f2')
    out = p.add_first(3, 'f3')  # over depth: the oldest frame is given up on
    assert out.dropped_first == [(1, 'f1')] and len(p) == 2
    p.add_second(9, 'v9')
    out = p.add_second(3, 'v3')  # a pair at 3: frame 2 can no longer be paired
    assert out.pairs == [(3, 'f3', 'v3')] and out.dropped_first == [(2, 'f2')]
    assert p.flush() == ([], [(9, 'v9')])
    out = p.add_first(5, 'a')
    assert p.add_first(5, 'b').dropped_first == [(5, 'a')]  # a repeated stamp replaces


def test_hold_queue_release_and_expiry() -> None:
    q: pairing.HoldQueue[int] = pairing.HoldQueue(depth=2, wait_s=1.0)
    assert q.add(1, 0.0) == [] and q.add(2, 0.5) == []
    assert q.add(3, 0.6) == [1]
    assert q.release(lambda x: x < 3) == [2] and len(q) == 1
    assert q.expire(1.5) == [] and q.expire(1.7) == [3]
    with pytest.raises(ValueError):
        pairing.HoldQueue(0, 1.0)
    with pytest.raises(ValueError):
        pairing.StampPairer(0)
