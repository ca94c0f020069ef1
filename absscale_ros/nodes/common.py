"""Pieces every node shares: QoS profiles, the step-mode acknowledgement, message classes."""
import ctypes
import importlib
from typing import Any, Iterable

from absscale_ros import conversions
from absscale_ros.core.errors import BagError
from absscale_ros.core.replay import Ack, DEFERRED
from rclpy.node import Node
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, qos_profile_sensor_data, QoSProfile,
                       ReliabilityPolicy)
from std_msgs.msg import Header

ACK_TOPIC = '/absscale/ack'
# Offline, the keyframe selector asks the vertex detector for a frame's vertices here
# (std_msgs/Header, the frame's stamp; ``detect_on_request``).
DETECT_REQUESTS_TOPIC = '/absscale/detect_requests'
# Offline (step mode), once every frame is acknowledged: one more step that the nodes holding
# state until the end (the sfm's final batch adjustment) answer with their last outputs.
END_OF_BAG_TOPIC = '/absscale/end_of_bag'
# Offline runs are lossless: reliable, and deep enough for the non-stepped messages that
# travel between two stepped frames (camera_info, diagnostics).
RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                      history=HistoryPolicy.KEEP_LAST)
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
SENSOR = qos_profile_sensor_data
LIVE = 'sensor_data'  # the ``qos`` parameter's value of a live run (``absscale run --live``)
# Decoded frames (2.7 MB at 1280x720): a graph_monitor that does not record counts them from the
# step acknowledgements that announce them, and bag_replay waits for it to hear those instead.
ANNOUNCED_IMAGE_TYPE = 'sensor_msgs/msg/Image'
# glibc mallopt parameters (malloc.h) and the values keep_freed_memory sets.
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
MMAP_THRESHOLD_BYTES = 32 << 20  # glibc's largest: every frame-sized buffer on the heap
TRIM_THRESHOLD_BYTES = 128 << 20  # free memory kept at the heap's top, at most


def live_input(depth: int) -> QoSProfile:
    """
    A live node's input between graph nodes: reliable (the publishers are), but only the
    newest ``depth`` messages are kept, so a node that is behind drops rather than queues.
    """
    return QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE,
                      history=HistoryPolicy.KEEP_LAST)


def message_class(msgtype: str) -> Any:
    """Return the rclpy class for ``'pkg/msg/Name'``; BagError if it is not installed."""
    try:
        pkg, kind, name = msgtype.split('/')
        return getattr(importlib.import_module(f'{pkg}.{kind}'), name)
    except (ValueError, ImportError, AttributeError) as err:
        raise BagError(f'unknown message type {msgtype!r} (no Python package provides it)') \
            from err


class DiagnosticsPublisher:
    """One node's ``/diagnostics`` output: a status named ``'<node>: <what>'`` per call."""

    def __init__(self, node: Node, what: str) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        self._node, self._name = node, f'{node.get_name()}: {what}'
        self._pub = node.create_publisher(DiagnosticArray, '/diagnostics', 10)

    def publish(self, level: str, message: str, values: dict[str, Any],
                stamp_ns: int | None = None) -> None:
        """Publish one status; the stamp defaults to the node's clock."""
        status = conversions.diagnostic_status(self._name, level, message, values)
        stamp = self._node.get_clock().now().nanoseconds if stamp_ns is None else stamp_ns
        self._pub.publish(conversions.diagnostic_array([status], stamp))


class StepAck:
    """Publishes the acknowledgement the lossless replay waits for (see core/replay.py)."""

    def __init__(self, node: Node) -> None:
        self._node = node
        self._pub = node.create_publisher(Header, ACK_TOPIC, RELIABLE)

    def ack(self, stamp: Any, input_topic: str, outputs: Iterable[str] = ()) -> None:
        """
        Say that this node handled ``input_topic`` at ``stamp`` and published ``outputs``.
        ``DEFERRED`` among the outputs: this node queued the work and acknowledges again, with
        ``input_topic`` ``DEFERRED``, once it published its outputs.
        """
        text = Ack(self._node.get_name(), self._resolve(input_topic), 0,
                   tuple(self._resolve(o) for o in outputs)).encode()
        self._pub.publish(conversions.ack_to_msg(text, stamp))

    def _resolve(self, topic: str) -> str:
        return topic if topic == DEFERRED else self._node.resolve_topic_name(topic)


def single_threaded_executor(context: Any = None) -> Any:
    """
    rclpy's EventsExecutor where this rclpy has it (Jazzy 7.1.2 and later), else the classic
    SingleThreadedExecutor. Same results; the events executor dispatches from C++ and cost
    11 % less CPU on the outdoor sample (the classic one rebuilds its wait set per callback).
    """
    try:
        from rclpy.experimental import EventsExecutor
    except ImportError:
        from rclpy.executors import SingleThreadedExecutor
        return SingleThreadedExecutor(context=context)
    return EventsExecutor(context=context)


def keep_freed_memory() -> None:
    """
    Let glibc reuse freed frame-sized buffers instead of returning them to the kernel.

    Every 1280x720 frame (2.7 MB) and each OpenCV or numpy image made from it is a large
    allocation: by default glibc maps it fresh (or trims the heap after it), and the kernel
    zeroes its pages again on first touch. Kept in the heap, they are reused as they are; the
    outdoor sample in one process took 10 % less CPU (sys time 3.0 -> 0.7 s). No effect where
    the C library is not glibc.
    """
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return
    mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)
    mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES)


def one_opencv_thread(threads: int = 1) -> int:
    """
    OpenCV without its worker threads, in a process that shares two cores with other busy
    processes (a split run's three) or threads (one process's decode, sfm and SIFT workers).
    Its pool's threads spin (sched_yield) while they wait for work: in a split run of the
    60 s bag that was 5-7 s of the three processes' 66-72 s of CPU
    (measured when the runner still decoded frames: runner -2.0, detector -3.2, sfm -1.6 s;
    the runner now only replays, the frame nodes' process gains most), and the other processes
    keep the second core busy anyway. Same keyframes, factor and cloud. Returns the count it
    replaced.
    """
    import cv2
    before = cv2.getNumThreads()
    cv2.setNumThreads(threads)
    return before


def run_node(node_cls: type, args: list[str] | None = None, threads: int = 1) -> None:
    """
    The console-script ``main`` of every node (Jazzy style, see STYLE.md).

    An expected failure while starting (bad parameter value, missing file) is one line and
    exit 1; a node with a ``finished`` attribute (bag_replay, video_source on a file) ends
    the process when it turns True. ``threads`` > 1 spins a MultiThreadedExecutor, for nodes
    whose slow work has a callback group of its own.
    """
    import rclpy
    from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor

    from absscale_ros.core.errors import AbsScaleError
    keep_freed_memory()
    rclpy.init(args=args)
    try:
        node = node_cls()
    except (AbsScaleError, ValueError) as err:
        print(f'{node_cls.__name__}: error: {err}')
        rclpy.try_shutdown()
        raise SystemExit(1)
    executor = MultiThreadedExecutor(num_threads=threads) if threads > 1 \
        else single_threaded_executor()
    executor.add_node(node)
    answers = _match_answers(node)
    try:
        while rclpy.ok() and not getattr(node, 'finished', False):
            executor.spin_once(timeout_sec=0.1)
            if answers is not None:
                answers.poll()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.shutdown()
        _write_report(node)
        node.destroy_node()
        rclpy.try_shutdown()


def _match_answers(node: Node) -> Any:
    """Started by ``absscale run --processes``: the runner's start check, answered (see
    ``node_processes.MatchAnswers``); else None."""
    import os
    from pathlib import Path

    from absscale_ros import node_processes
    folder = os.environ.get(node_processes.MATCH_DIR_ENV)
    return node_processes.MatchAnswers(Path(folder), node.get_name(), [node]) if folder \
        else None


def _write_report(node: Any) -> None:
    """With ABSSCALE_REPORT set (``absscale run --processes``), leave ``report()`` there."""
    import json
    import os
    import time
    path = os.environ.get('ABSSCALE_REPORT')
    if path and callable(getattr(node, 'report', None)):
        # The process's CPU time: which node used the machine (live runs share two cores).
        report = {**node.report(), 'process_cpu_s': round(time.process_time(), 2)}
        write_whole(path, json.dumps(report, default=str))


def write_whole(path: str, text: str) -> None:
    """Write ``text`` to ``path`` so that a reader never sees it half written (a rename)."""
    import os
    with open(f'{path}.tmp', 'w') as f:
        f.write(text)
    os.replace(f'{path}.tmp', path)


def declare_config(node: Node, cfg: Any, prefix: str = '') -> Any:
    """
    Declare one parameter per field of the config dataclass ``cfg`` (its values are the
    defaults) and return the config built from the parameters, validated by its own checks.
    """
    from dataclasses import fields, replace
    from rclpy.parameter import Parameter
    values = {}
    for f in fields(cfg):
        default = getattr(cfg, f.name)
        name = f'{prefix}.{f.name}' if prefix else f.name
        if isinstance(default, tuple) and not default:
            # rclpy types an empty list as a byte array, which then refuses a YAML list of
            # names; the one such field (``sheet.other_sheets``) holds names.
            value = node.declare_parameter(name, Parameter.Type.STRING_ARRAY).value or []
        else:
            value = node.declare_parameter(name, list(default) if isinstance(default, tuple)
                                           else default).value
        values[f.name] = tuple(value) if isinstance(default, tuple) else value
    return replace(cfg, **values)
