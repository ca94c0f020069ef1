"""Causal step tracking: a step completes only when every acking consumer has drained it."""
from absscale_ros.core.replay import Ack, DEFERRED, due_wall_ns, StepTracker, StepWindow
import pytest

GRAPH = {
    '/cam': ['ingest'],
    '/frames': ['detector', 'selector'],
    '/vertices': ['selector'],
    '/keyframes': ['sfm'],
}


def tracker() -> StepTracker:
    return StepTracker(lambda topic: GRAPH.get(topic, []))


def test_step_completes_after_whole_chain() -> None:
    t = tracker()
    t.start('/cam', 5)
    assert not t.done
    t.on_ack(Ack('ingest', '/cam', 5, ('/frames',)))
    assert t.pending() == ['detector on /frames', 'selector on /frames']
    t.on_ack(Ack('detector', '/frames', 5, ('/vertices',)))
    t.on_ack(Ack('selector', '/frames', 5))
    assert not t.done  # selector still owes the vertices
    t.on_ack(Ack('selector', '/vertices', 5, ('/keyframes',)))
    assert t.pending() == ['sfm on /keyframes']
    t.on_ack(Ack('sfm', '/keyframes', 5))
    assert t.done


def test_ack_overtaking_its_announcement_is_not_lost() -> None:
    t = tracker()
    t.start('/cam', 7)
    t.on_ack(Ack('detector', '/frames', 7))
    t.on_ack(Ack('selector', '/frames', 7))
    assert not t.done
    t.on_ack(Ack('ingest', '/cam', 7, ('/frames',)))
    assert t.done


def test_stale_ack_is_ignored() -> None:
    t = tracker()
    t.start('/cam', 9)
    assert not t.on_ack(Ack('ingest', '/cam', 8))
    assert not t.done


def test_topic_without_ackers_completes_at_once() -> None:
    t = tracker()
    t.start('/nobody', 1)
    assert t.done


def test_ack_text_round_trip_and_malformed() -> None:
    ack = Ack('sfm', '/absscale/keyframes', 3, ('/a', '/b'))
    assert Ack.decode(ack.encode(), 3) == ack
    with pytest.raises(ValueError, match='malformed ack'):
        Ack.decode('nonsense', 0)


def test_due_time_scales_with_rate() -> None:
    assert due_wall_ns(2_000, 1_000, 50, 2.0) == 550
    with pytest.raises(ValueError):
        due_wall_ns(0, 0, 0, 0.0)


def test_output_announced_by_two_acks_is_awaited_once() -> None:
    """A node consuming two inputs may name its outputs in both acknowledgements."""
    t = tracker()
    t.start('/vertices', 4)
    t.on_ack(Ack('selector', '/vertices', 4, ('/keyframes',)))
    t.on_ack(Ack('sfm', '/keyframes', 4))
    t.on_ack(Ack('selector', '/vertices', 4, ('/keyframes',)))
    assert t.done


def test_window_keeps_several_frames_in_flight_and_completes_them_out_of_order() -> None:
    w = StepWindow(lambda topic: GRAPH.get(topic, []), size=2)
    w.start('/cam', 1, now=0.0)
    assert not w.full
    w.start('/cam', 2, now=0.1)
    assert w.full
    w.on_ack(Ack('ingest', '/cam', 2), now=0.0)  # frame 2 drains first
    assert not w.full and not w.empty
    assert not w.on_ack(Ack('ingest', '/cam', 7), now=0.0)  # a stamp not in flight changes nothing
    assert w.on_ack(Ack('ingest', '/cam', 1), now=0.0)
    assert w.empty


def test_window_expires_only_steps_older_than_the_timeout() -> None:
    w = StepWindow(lambda topic: GRAPH.get(topic, []), size=3)
    w.start('/cam', 1, now=0.0)
    w.start('/cam', 2, now=5.0)
    w.start('/nobody', 3, now=5.0)  # no consumer: complete at once, never in flight
    assert w.expire(now=10.0, timeout_s=8.0) == [(1, ['ingest on /cam'])]
    assert not w.empty and w.expire(now=10.0, timeout_s=8.0) == []
    with pytest.raises(ValueError):
        StepWindow(lambda topic: [], size=0)


QUEUED = {**GRAPH, '/map': ['scale']}


def test_deferred_step_leaves_the_window_but_not_the_drain() -> None:
    """A node that queues its work acknowledges DEFERRED: the window goes on without it, but
    the replay is not drained until its second acknowledgement and its outputs' consumers."""
    w = StepWindow(lambda topic: QUEUED.get(topic, []), size=1)
    w.start('/keyframes', 1, now=0.0)
    assert w.full
    assert w.on_ack(Ack('sfm', '/keyframes', 1, (DEFERRED,)), now=1.0)  # queued: a place frees
    assert not w.full and not w.empty and w.deferred_total == 1
    assert not w.on_ack(Ack('sfm', DEFERRED, 1, ('/map',)), now=2.0)  # published: scale owes /map
    assert not w.empty
    assert w.on_ack(Ack('scale', '/map', 1), now=3.0)
    assert w.empty


def test_deferred_ack_overtaking_the_first_one_is_not_lost() -> None:
    """The queue's worker can acknowledge before the callback that queued it does."""
    t = StepTracker(lambda topic: QUEUED.get(topic, []))
    t.start('/keyframes', 2)
    t.on_ack(Ack('sfm', DEFERRED, 2, ()))  # e.g. a keyframe dropped at once, no outputs
    t.on_ack(Ack('sfm', '/keyframes', 2, (DEFERRED,)))
    assert t.done


def test_deferred_step_expires_counted_from_when_it_was_deferred() -> None:
    w = StepWindow(lambda topic: QUEUED.get(topic, []), size=2)
    w.start('/keyframes', 3, now=0.0)
    w.on_ack(Ack('sfm', '/keyframes', 3, (DEFERRED,)), now=9.0)
    assert w.expire(now=10.0, timeout_s=5.0) == []
    assert w.expire(now=14.5, timeout_s=5.0) == [(3, ['sfm on deferred'])]
    assert w.empty


def test_deferred_steps_queued_behind_another_wait_from_when_it_completed() -> None:
    """The queue is worked in order: a step's timeout restarts once the one before it drained."""
    w = StepWindow(lambda topic: QUEUED.get(topic, []), size=4)
    for stamp in (4, 5):
        w.start('/keyframes', stamp, now=0.0)
        w.on_ack(Ack('sfm', '/keyframes', stamp, (DEFERRED,)), now=1.0)
    w.on_ack(Ack('sfm', DEFERRED, 4, ()), now=5.5)  # the first is mapped after 4.5 s
    assert w.expire(now=6.5, timeout_s=5.0) == []  # the second's clock restarted at 5.5
    assert w.expire(now=10.5, timeout_s=5.0) == [(5, ['sfm on deferred'])]
