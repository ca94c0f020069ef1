"""
Run the whole node graph in one process over a bag: the engine behind ``absscale run``.

Every node of the pipeline that exists is started with its section of the config, then
``bag_replay`` steps the bag through them losslessly; the run ends when the bag is done and
the graph has drained the last frame.
"""
from dataclasses import dataclass, field
import importlib
import os
import time
from typing import Any, Callable

from absscale_ros import params
from absscale_ros.nodes.bag_replay import BagReplayNode
from absscale_ros.nodes.graph_monitor import GraphMonitorNode
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter

# Pipeline nodes in data-flow order: (node name, module, class). Each later issue adds its own.
PIPELINE: list[tuple[str, str, str]] = [
    ('frame_ingest', 'absscale_ros.nodes.frame_ingest', 'FrameIngestNode'),
    ('vertex_detector', 'absscale_ros.nodes.vertex_detector', 'VertexDetectorNode'),
    ('keyframe_selector', 'absscale_ros.nodes.keyframe_selector', 'KeyframeSelectorNode'),
    ('sfm', 'absscale_ros.nodes.sfm', 'SfmNode'),
    ('scale', 'absscale_ros.nodes.scale', 'ScaleNode'),
]


@dataclass
class Progress:
    """What the runner knows mid-run, for a progress bar."""

    published: int = 0
    total: int = 0
    steps: int = 0
    elapsed_s: float = 0.0
    nodes: dict[str, Node] = field(default_factory=dict)


def available_nodes() -> list[tuple[str, type]]:
    """The pipeline nodes whose modules exist in this checkout, in data-flow order."""
    found = []
    for name, module, cls in PIPELINE:
        if importlib.util.find_spec(module) is not None:
            found.append((name, getattr(importlib.import_module(module), cls)))
    return found


def _overrides(values: dict[str, Any]) -> list[Parameter]:
    return [Parameter(k, value=v) for k, v in values.items()]


def run_graph(bag: str, config: str, replay_overrides: dict[str, Any] | None = None,
              on_progress: Callable[[Progress], None] | None = None,
              drain_s: float = 0.3, domain_id: int | None = None,
              record: str | None = None) -> dict[str, Any]:
    """
    Replay ``bag`` through every available node; return the report (a JSON-able dict).

    :param config: config name or YAML path (see ``params.find_config``).
    :param replay_overrides: bag_replay parameters that win over the config (mode, rate...).
    :param domain_id: DDS domain; None picks one from the process id, so offline runs on one
        machine never hear each other.
    :param record: MCAP file to record every graph topic into (not the bag's own topics).
    :raises AbsScaleError: bad bag or config (before any node runs).
    """
    config_path = params.find_config(config)
    sections = params.load_yaml(config_path)
    context = rclpy.Context()
    rclpy.init(context=context, args=[],
               domain_id=1 + os.getpid() % 100 if domain_id is None else domain_id)
    nodes: dict[str, Node] = {}
    monitor = None
    try:
        found = available_nodes()
        for name, cls in found:
            values = params.node_params(sections, name)
            if name == 'keyframe_selector' and 'vertex_detector' not in dict(found):
                values['use_vertices'] = False  # no detector: frames alone decide
            nodes[name] = cls(context=context, parameter_overrides=_overrides(values))
        monitor = GraphMonitorNode(context=context)
        monitor.discover()  # the pipeline's topics exist now: count them from the first message
        if record:
            monitor.record(record)
        replay_params = params.node_params(sections, 'bag_replay')
        replay_params.update(bag=str(bag), expect_nodes=','.join(nodes),
                             **(replay_overrides or {}))
        replay = BagReplayNode(context=context, parameter_overrides=_overrides(replay_params))
        for topic, msgtype in replay.topic_types().items():
            monitor.watch(topic, msgtype, recorded=False)
        executor = SingleThreadedExecutor(context=context)
        for node in [*nodes.values(), monitor, replay]:
            executor.add_node(node)
        t0 = time.monotonic()
        progress = Progress(total=replay.total, nodes=nodes)
        last_report = 0.0
        while not replay.finished:
            executor.spin_once(timeout_sec=0.05)
            now = time.monotonic()
            if on_progress is not None and now - last_report > 0.2:
                last_report = now
                progress.published, progress.steps = replay.published, replay.steps
                progress.elapsed_s = now - t0
                on_progress(progress)
        _drain(executor, monitor, drain_s)
        wall_s = time.monotonic() - t0
        report = {
            'bag': str(bag), 'config': str(config_path), 'wall_time_s': round(wall_s, 3),
            'replay': {'mode': replay_params.get('mode', 'rate'), 'published': replay.published,
                       'total': replay.total, 'steps': replay.steps,
                       'step_timeouts': replay.timeouts},
            'nodes': {name: _node_report(node) for name, node in nodes.items()},
            **monitor.report(),
        }
        report['detections'] = list(monitor.detections)
        report['_latest'] = dict(monitor.latest)  # popped by the caller that writes files
        if on_progress is not None:
            progress.published, progress.steps, progress.elapsed_s = \
                replay.published, replay.steps, wall_s
            on_progress(progress)
        return report
    finally:
        if monitor is not None:
            monitor.close()
        for node in nodes.values():
            node.destroy_node()
        rclpy.try_shutdown(context=context)


def _drain(executor: SingleThreadedExecutor, monitor: GraphMonitorNode, quiet_s: float) -> None:
    """Spin until no message has moved for ``quiet_s`` (late diagnostics, last clouds)."""
    deadline = time.monotonic() + 10.0
    quiet_since, seen = time.monotonic(), monitor.total
    while time.monotonic() - quiet_since < quiet_s and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.02)
        if monitor.total != seen:
            quiet_since, seen = time.monotonic(), monitor.total


def _node_report(node: Node) -> dict[str, Any]:
    report = getattr(node, 'report', None)
    return report() if callable(report) else {}
