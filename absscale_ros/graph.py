"""
Run the whole node graph in one process over a bag: the engine behind ``absscale run``.

Every node of the pipeline that exists is started with its section of the config, then
``bag_replay`` steps the bag through them losslessly; the run ends when the bag is done and
the graph has drained the last frame.
"""
from dataclasses import dataclass
import importlib
import importlib.util
import os
import resource
import time
from typing import Any, Callable

from absscale_ros import node_processes, params
from absscale_ros.core.errors import AbsScaleError
from absscale_ros.domains import DomainLease
from absscale_ros.nodes import common
from absscale_ros.nodes.bag_replay import BagReplayNode
from absscale_ros.nodes.graph_monitor import GraphMonitorNode
import numpy as np
import rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter

# Pipeline nodes in data-flow order: (node name, module, class). Each later issue adds its own.
PIPELINE: list[tuple[str, str, str]] = [
    ('frame_ingest', 'absscale_ros.nodes.frame_ingest', 'FrameIngestNode'),
    ('vertex_detector', 'absscale_ros.nodes.vertex_detector', 'VertexDetectorNode'),
    ('keyframe_selector', 'absscale_ros.nodes.keyframe_selector', 'KeyframeSelectorNode'),
    ('sfm', 'absscale_ros.nodes.sfm', 'SfmNode'),
    ('scale', 'absscale_ros.nodes.scale', 'ScaleNode'),
    ('dense', 'absscale_ros.nodes.dense', 'DenseNode'),
]
MEMORY_PERIOD_S = 5.0
KEYFRAMES_TOPIC, KEYFRAME_PATH_TOPIC = '/absscale/keyframes', '/absscale/keyframe_path'
SFM_STATUS = 'sfm: reconstruction'  # its diagnostics count the keyframes a live SfM skipped
DRAIN_LIMIT_S = 300.0  # after the bag: the longest wait for the graph to catch up
STALLED_S = 10.0  # nothing moved this long: the graph is not catching up, stop waiting
# A split run's other processes (RunOptions.split), one per group; the rest stay in the runner.
# The nodes that take every decoded frame share one process: a 2.7 MB frame sent to another
# process cost ~1.2 ms of CPU to publish and ~1.5 ms to take (Fast DDS shared memory, measured
# apart), against ~0.7 ms for both within one. With ingest and the selector in the runner and
# the detector apart, 60 s bag under load: CPU 67.1 / 64.7 s (runner 19.6, detector 22.5,
# sfm + scale 23.3) -> 60.8 / 61.3 s (runner 3.9, frames 32.8, sfm + scale 22.1), wall x0.77 /
# x1.00 interleaved; the runner only replays the bag (JPEG) and watches. The scale node stays
# in the runner too: beside the sfm it took ~1 s of that process's CPU (and its GIL), and the
# sfm's process is a split run's critical path at the end (see SPLIT_NICE); the runner has CPU
# to spare. 60 s bag, 6 interleaved pairs at load 5-11: sfm process 23.1-24.4 -> 21.8-22.9 s
# CPU in 5 of them (22.6 -> 24.6 in one), replay x0.95-1.07 (median x0.97; two pairs in which
# another job held the new runs to one core left out), the same factor and cloud in every run.
SPLIT_GROUPS = (('frame_ingest', 'vertex_detector', 'keyframe_selector'),
                ('sfm', 'dense'))
# ... and the niceness added to a group's process. The sfm is a split run's critical path: its
# final batch comes last, after every keyframe it queued. At the detector's priority it worked
# off its queue (a 3.9 s batch among it on the 60 s bag) alone after the replay; with the
# detector at nice 5 it keeps up and the frames wait instead (replay end to exit 8.3-11.3 s ->
# 7.2-8.5 s, 4 alternating pairs; the same factor and cloud). Now the frame nodes' process
# (see SPLIT_GROUPS): at nice 0 it took x0.91 / x1.07 the wall, 2 pairs under load, no better.
SPLIT_NICE = {'vertex_detector': 5}
# With the dense node on, it owns /scaled_cloud and the sparse metric cloud moves here.
SPARSE_METRIC_TOPIC = '/absscale/sparse_cloud_metric'


@dataclass
class Progress:
    """What the runner knows mid-run, for a progress bar."""

    published: int = 0
    total: int = 0
    steps: int = 0
    keyframes: int = 0
    scale: tuple[float, float] | None = None  # (factor, sigma) once established
    elapsed_s: float = 0.0


@dataclass(frozen=True)
class RunOptions:
    """
    How to run the graph over a bag.

    :param live: replay at bag rate into sensor-data QoS; nodes that fall behind drop frames
        (and the sfm keyframes) instead of queueing them (a camera's view).
    """

    mode: str = 'step'
    rate: float = 1.0
    live: bool = False
    domain_id: int | None = None  # None: a private one from the process id
    record: str | None = None  # MCAP file for every graph topic (not the bag's own)
    drain_s: float = 0.3
    processes: bool = False  # each pipeline node in its own process, over real DDS
    # Offline, not --processes: the frame nodes (ingest, detector, keyframe selector), and the
    # SfM, in processes of their own (SPLIT_GROUPS; scale stays here), so a run uses both
    # cores (opt-in: under load it once lost a keyframe's input at start, and the indoor sample
    # then claimed no scale; one process is the tested default).
    split: bool = False


def dense_enabled(sections: dict[str, dict[str, Any]]) -> bool:
    """Whether the config turns the optional dense node on (``dense: enabled``)."""
    return bool(params.node_params(sections, 'dense').get('enabled', False))


def available_modules(sections: dict[str, dict[str, Any]] | None = None
                      ) -> list[tuple[str, str]]:
    """(node name, module) of the pipeline nodes whose modules exist in this checkout (the
    dense node only when the config's ``sections`` enable it), in data-flow order; nothing is
    imported (a --processes runner would spend seconds importing what its nodes run)."""
    return [(name, module) for name, module, _ in PIPELINE
            if (name != 'dense' or dense_enabled(sections or {}))
            and importlib.util.find_spec(module) is not None]


def available_nodes(sections: dict[str, dict[str, Any]] | None = None
                    ) -> list[tuple[str, type]]:
    """The pipeline nodes of ``available_modules``, as their node classes."""
    classes = {name: cls for name, _, cls in PIPELINE}
    return [(name, getattr(importlib.import_module(module), classes[name]))
            for name, module in available_modules(sections)]


def _check_step_window(sections: dict[str, dict[str, Any]]) -> None:
    """
    Refuse a step window wider than a node's stamp pairing: the frames in flight would outrun
    their vertices, be decided unpaired and give another result on every run (window 16
    against pair_depth 10: 66-79 of 300 frames unpaired, two different factors in two runs).
    Refuse a detector that waits for the selector's requests when the selector sends none.
    """
    window = int(params.node_params(sections, 'bag_replay').get('step_window', 1))
    for node in ('keyframe_selector', 'sfm', 'vertex_detector'):
        depth = int(params.node_params(sections, node).get('pair_depth', 10))
        if window > depth:
            raise AbsScaleError(f'bag_replay step_window {window} > {node} pair_depth {depth}: '
                                'frames would be decided without their vertices; raise '
                                'pair_depth or lower step_window')
    asks, answers = (bool(params.node_params(sections, node).get('detect_on_request', False))
                     for node in ('keyframe_selector', 'vertex_detector'))
    if answers and not asks:  # the detector would wait for requests that never come
        raise AbsScaleError('vertex_detector detect_on_request needs keyframe_selector '
                            'detect_on_request')


def _overrides(values: dict[str, Any]) -> list[Parameter]:
    return [Parameter(k, value=v) for k, v in values.items()]


# Runs in one process (benches) each get their own domain: the nodes of a finished run linger
# in DDS discovery for a while and the lossless replay would wait for their acknowledgements.
def _node_values(name: str, sections: dict[str, dict[str, Any]], names: list[str],
                 live: bool) -> dict[str, Any]:
    """The parameters of pipeline node ``name`` in a run of the nodes ``names``."""
    values = params.node_params(sections, name)
    if name == 'scale' and dense_enabled(sections):
        values['cloud_topic'] = SPARSE_METRIC_TOPIC
    if name == 'scale':
        values.update(params.scale_sheet(sections))
    if name == 'keyframe_selector' and 'vertex_detector' not in names:
        values['use_vertices'] = False  # no detector: frames alone decide
    if live:
        values['qos'] = 'sensor_data'  # nodes that have this parameter drop when behind
    return values


def start_nodes(context: rclpy.Context, sections: dict[str, dict[str, Any]],
                live: bool, only: list[str] | None = None, runner: bool = True
                ) -> dict[str, Node]:
    """
    Start the available pipeline nodes (those in ``only``, if given) in this process. In the
    ``runner``'s own process the sfm maps its queued keyframes on the executor's thread (on
    the runner's one interpreter a worker would contend for the GIL), each once its features
    are detected: that detection then overlaps the frame nodes' work.
    """
    names = [name for name, _ in available_modules(sections)]
    classes = {name: (module, cls) for name, module, cls in PIPELINE}
    nodes: dict[str, Node] = {}
    for name in names:
        if only is None or name in only:
            cls = getattr(importlib.import_module(classes[name][0]), classes[name][1])
            values = _node_values(name, sections, names, live)
            if runner and name == 'sfm':
                values['queue_worker'] = False
            nodes[name] = cls(context=context, parameter_overrides=_overrides(values))
    return nodes


def run_graph(bag: str, config: str, options: RunOptions = RunOptions(),
              on_progress: Callable[[Progress], None] | None = None,
              inspect: Callable[[dict[str, Node]], None] | None = None) -> dict[str, Any]:
    """
    Replay ``bag`` through every available node; return the report (a JSON-able dict).

    :param config: config name or YAML path (see ``params.find_config``).
    :param inspect: called with the nodes of this process after the run, before they are
        destroyed (a bench reads the sfm's map there; nodes in other processes are not in it).
    :raises AbsScaleError: bad bag or config (before any node runs).
    """
    config_path = params.find_config(config)
    sections = params.load_yaml(config_path)
    common.keep_freed_memory()
    if options.mode == 'step' and not options.live:
        _check_step_window(sections)
    lease = DomainLease() if options.domain_id is None else None
    # Read when a process's first DDS participant starts; node processes inherit it.
    os.environ.update(params.dds_environment())
    context = rclpy.Context()
    rclpy.init(context=context, args=[], domain_id=options.domain_id if lease is None
               else lease.domain_id)
    nodes: dict[str, Node] = {}
    monitor = executor = children = cv_threads = None
    try:
        names = [name for name, _ in available_modules(sections)]
        # All nodes in one process too: OpenCV's pool threads spin between jobs, and the
        # decode, sfm and SIFT threads want the second core (60 s bag, one process: 64.6 /
        # 65.9 -> 55.7 / 57.6 s of CPU, same factor and cloud).
        cv_threads = common.one_opencv_thread()
        domain = context.get_domain_id()
        if options.processes:
            children = node_processes.NodeProcesses(config_path, domain, options.live,
                                                    [[name] for name in names], own_main=True)
        else:
            groups = [[n for n in names if n in group] for group in SPLIT_GROUPS] \
                if options.split and not options.live else []
            groups = [g for g in groups if g]
            if groups:  # started first: their processes import while this one does
                children = node_processes.NodeProcesses(config_path, domain, False, groups,
                                                        nice=SPLIT_NICE)
            nodes = start_nodes(context, sections, options.live,
                                [n for n in names if not any(n in g for g in groups)])
        monitor = GraphMonitorNode(context=context)
        monitor.discover()  # the pipeline's topics exist now: count them from the first message
        if options.record:
            monitor.record(options.record)
        replay_params = _replay_params(sections, bag, names, options, monitor.get_name(),
                                       across_processes=children is not None)
        replay = BagReplayNode(context=context, parameter_overrides=_overrides(replay_params))
        if children is not None:
            # Matching across processes can lag discovery by seconds on a busy machine, and a
            # frame sent before a node's input matched is lost (seen as one step timeout): the
            # replay starts once every endpoint on either side matched all it discovered
            # (was a fixed 5 s settle with --processes).
            local = [*nodes.values(), monitor, replay]
            replay.gate = lambda: children.matched(local)
        for topic, msgtype in replay.topic_types().items():
            monitor.watch(topic, msgtype, recorded=False, best_effort=options.live)
        # One thread: GTSAM holds the GIL, so threads would not overlap the stages and rclpy's
        # multi-threaded executor costs ~40 % more CPU (measured on the sample bag). A step
        # window > 1 overlaps the stages across processes (--processes). Live too: the live
        # sfm adds keyframes on a thread of its own, and three executor threads had cost the
        # 60 s bag 51 s of CPU in a --processes runner (replay and monitor alone; now 23 s)
        # and, all nodes in one process, lost 28-48 % of the frames (now 6-11 %).
        executor = common.single_threaded_executor(context)
        for node in [*nodes.values(), monitor, replay]:
            executor.add_node(node)
        memory: list[list[float]] = []
        wall_s = _spin(executor, replay, monitor, nodes, options, on_progress, memory)
        node_reports = {name: node_report(node) for name, node in nodes.items()}
        if inspect is not None:
            inspect(nodes)
        if children is not None:
            node_reports.update(children.stop())
        node_reports = {name: node_reports[name] for name in names if name in node_reports}
        return _report(bag, config_path, wall_s, replay_params['mode'], options.live, replay,
                       monitor, node_reports, children, memory)
    finally:
        if children is not None:
            children.stop()
        if executor is not None:
            executor.shutdown(timeout_sec=5.0)  # worker threads stop before the nodes go
        if monitor is not None:
            monitor.close()
        for node in nodes.values():
            node.destroy_node()
        rclpy.try_shutdown(context=context)
        if lease is not None:  # not while node processes may still be on its domain
            lease.release() if children is None else children.reaped(lease.release)
        if cv_threads is not None:
            common.one_opencv_thread(cv_threads)  # as it was for whatever runs next here


def _replay_params(sections: dict[str, dict[str, Any]], bag: str, names: list[str],
                   options: RunOptions, observer: str, across_processes: bool) -> dict[str, Any]:
    """The bag_replay node's parameters for this run: its config section, then the run's."""
    values = params.node_params(sections, 'bag_replay')
    values.update(bag=str(bag), expect_nodes=','.join(names), mode=options.mode,
                  rate=options.rate, observer=observer, observer_images=bool(options.record))
    if across_processes:  # discovery across processes takes longer than in one
        values['startup_timeout_s'] = max(30.0, values.get('startup_timeout_s', 5.0))
    if options.live:
        values.update(mode='rate', qos='sensor_data')
    return values


def _report(bag: str, config_path: Any, wall_s: float, mode: str, live: bool,
            replay: BagReplayNode, monitor: GraphMonitorNode, node_reports: dict[str, Any],
            children: node_processes.NodeProcesses | None,
            memory: list[list[float]]) -> dict[str, Any]:
    """The run's report.json (before the caller pops ``_latest`` and writes the files)."""
    return {
        'bag': str(bag), 'config': str(config_path), 'wall_time_s': round(wall_s, 3),
        'replay': {'mode': mode, 'live': live,
                   'published': replay.published, 'total': replay.total,
                   'steps': replay.steps, 'step_timeouts': replay.timeouts,
                   'steps_deferred': replay.steps_deferred},
        'nodes': node_reports,
        **monitor.report(),
        'latency_s': _latency(replay.published_at, monitor.cloud_updates,
                              node_reports.get('keyframe_selector', {}).get(
                                  'keyframe_stamps_ns', []),
                              node_reports.get('sfm', {}).pop('timeline_ns', [])),
        'frames_not_processed': _frames_not_processed(len(replay.published_at),
                                                      node_reports),
        # CPU s per process: which node used the machine (live runs share its cores).
        'process_cpu_s': {'runner': round(time.process_time(), 2),
                          **(children.cpu_s if children is not None else {})},
        # ru_maxrss is in KiB on Linux; with --processes this is the runner alone.
        'peak_rss_mb': round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        'rss_mb': memory,  # [wall s, frames replayed, resident MB] every MEMORY_PERIOD_S
        'detections': list(monitor.detections),
        '_latest': dict(monitor.latest),  # popped by the caller that writes files
    }


def _spin(executor: Any, replay: BagReplayNode, monitor: GraphMonitorNode,
          nodes: dict[str, Node], options: RunOptions,
          on_progress: Callable[[Progress], None] | None, memory: list[list[float]]) -> float:
    """
    Spin until the bag is replayed and the graph has drained; return the wall time, s.

    :param memory: receives [elapsed s, frames replayed, resident MB] samples (a long run's
        growth shows whether anything accumulates per frame).
    """
    t0 = time.monotonic()
    last = 0.0
    while True:
        if time.monotonic() - t0 >= len(memory) * MEMORY_PERIOD_S:
            memory.append([round(time.monotonic() - t0, 1), replay.steps, _resident_mb()])
        done = replay.drained
        if done:
            _drain(executor, monitor, options.drain_s)
        now = time.monotonic()
        if on_progress is not None and (done or now - last > 0.2):
            last = now
            on_progress(_progress(replay, nodes, monitor, now - t0))
        if done:
            return now - t0
        executor.spin_once(timeout_sec=0.05)


def _resident_mb() -> float:
    """This process's resident set now (ru_maxrss is only the peak)."""
    with open('/proc/self/statm') as f:
        pages = int(f.read().split()[1])
    return round(pages * os.sysconf('SC_PAGE_SIZE') / 2**20, 1)


def _progress(replay: BagReplayNode, nodes: dict[str, Node], monitor: GraphMonitorNode,
              elapsed_s: float) -> Progress:
    selector, scaler = nodes.get('keyframe_selector'), nodes.get('scale')
    # Nodes in other processes say it in their diagnostics.
    keyframes, claimed = _progress_from_diagnostics(monitor.diagnostics)
    if selector is not None:
        keyframes = len(getattr(selector, 'keyframe_stamps_ns', ()))
    if scaler is not None:
        estimate = getattr(scaler, 'estimate', None)
        claimed = None if estimate is None else (estimate.factor, estimate.sigma)
    return Progress(replay.published, replay.total, replay.steps, keyframes, claimed, elapsed_s)


def _progress_from_diagnostics(diagnostics: dict[str, dict[str, Any]]
                               ) -> tuple[int, tuple[float, float] | None]:
    """Keyframes so far and (factor, sigma) once claimed, from the latest diagnostics."""
    keyframes = diagnostics.get('keyframe_selector: keyframes', {}).get('values', {})
    scale = diagnostics.get('scale: metric scale', {}).get('values', {})
    try:
        claimed = (float(scale['factor']), float(scale['sigma'])) \
            if scale.get('observable') == 'True' else None
        return int(keyframes.get('keyframes', 0)), claimed
    except (KeyError, ValueError):
        return 0, None


def _latency(published_at: dict[int, int], updates: list[tuple[int, int]],
             keyframe_stamps: list[int] = (),
             sfm_timeline: list[tuple[int, int, int, int]] = ()) -> dict[str, Any]:
    """
    Seconds from a keyframe's frame leaving the replay to the first /scaled_cloud update that
    includes it: stamped with it or, for a keyframe the live SfM skipped for a newer one, with
    a later keyframe. Only the first update per stamp counts (the scale node republishes the
    cloud when the path and the new factor follow). Keyframes before the first update (no
    scale yet) have none; those after it that no update reached are counted as ``never``.
    ``per_update``: the same for the keyframes an update is stamped with, skipped ones aside.
    Without keyframe stamps, every update's own keyframe. ``stages``: where it goes, from the
    live SfM's (stamp, image arrived, update started, ended) per keyframe (see ``_stages``).
    """
    first_at: dict[int, int] = {}  # stamp -> first arrival, monotonic ns
    for stamp, t in updates:
        if stamp in published_at and stamp not in first_at:
            first_at[stamp] = t
    if not first_at:
        return {'updates': 0}
    own = sorted(first_at)
    wanted = sorted(k for k in keyframe_stamps if k in published_at and k >= own[0]) or own
    seen, never = [], 0
    for k in wanted:
        reached = [t for stamp, t in first_at.items() if stamp >= k]
        if reached:
            seen.append((k, (min(reached) - published_at[k]) / 1e9))
        else:
            never += 1
    start = min(published_at.values())
    # (seconds into the replay the frame was published, its latency): where a backlog grows.
    series = [[round((published_at[k] - start) / 1e9, 3), round(s, 3)] for k, s in seen]
    lat = [s for _, s in seen]
    per_update = [(first_at[k] - published_at[k]) / 1e9 for k in own]
    out = {'updates': len(own), 'keyframes': len(seen), 'never': never,
           'median': float(np.median(lat)), 'p95': float(np.percentile(lat, 95)),
           'max': float(np.max(lat)), 'series': series,
           'per_update': {'median': float(np.median(per_update)),
                          'p95': float(np.percentile(per_update, 95))}}
    stages = _stages(published_at, first_at, sfm_timeline)
    if stages:
        out['stages'] = stages
    return out


def _stages(published_at: dict[int, int], first_at: dict[int, int],
            timeline: list[tuple[int, int, int, int]]) -> dict[str, dict[str, float]]:
    """
    Median and p95 seconds of each stage of a keyframe's latency: ``to_sfm`` (replay to the
    SfM: decoding, detection, the selector), ``waiting`` (behind the previous update),
    ``update`` (the SfM's) and ``to_cloud`` (publishing, the scale node, transport).
    """
    rows = [(arrived - published_at[stamp], started - arrived, ended - started,
             first_at[stamp] - ended) for stamp, arrived, started, ended in timeline
            if stamp in published_at and stamp in first_at]
    if not rows:
        return {}
    cols = np.array(rows, float).T / 1e9
    return {name: {'median': round(float(np.median(c)), 3),
                   'p95': round(float(np.percentile(c, 95)), 3)}
            for name, c in zip(('to_sfm', 'waiting', 'update', 'to_cloud'), cols)}


def _frames_not_processed(frames: int, node_reports: dict[str, Any]) -> dict[str, Any]:
    """
    Per frame-rate node, the bag's frames it lost (live: dropped by sensor-data QoS when
    behind), as a count and a share; frames the detector's live rate cap passed over are
    counted apart, and so are the frames it was not asked for (offline, ``detect_on_request``)
    and the keyframes a live SfM skipped. Offline all are zero.
    """
    handled = {'frame_ingest': 'frames_decoded', 'vertex_detector': 'frames',
               'keyframe_selector': 'frames'}
    out: dict[str, Any] = {'frames': frames}
    for node, key in handled.items():
        count = node_reports.get(node, {}).get(key)
        if count is None or not frames:
            continue
        # Frames a live detector passed over by its rate cap were not lost: counted apart.
        by_rate = int(node_reports[node].get('frames_skipped_by_rate', 0))
        unasked = int(node_reports[node].get('frames_not_requested', 0))  # decided without
        lost = frames - int(count) - by_rate - unasked
        out[node] = {'count': lost, 'share': round(lost / frames, 4)}
        if unasked:
            out[node]['not_requested'] = unasked
        if by_rate:
            out[node]['skipped_by_rate'] = by_rate
    # Keyframes the live SfM skipped for a newer one (their tracked steps were chained on).
    sfm, selector = node_reports.get('sfm', {}), node_reports.get('keyframe_selector', {})
    if sfm.get('keyframes_skipped') and selector.get('keyframes'):
        n = int(sfm['keyframes_skipped'])
        out['sfm_keyframes_skipped'] = {'count': n,
                                        'share': round(n / int(selector['keyframes']), 4)}
    return out


def _drain(executor: Any, monitor: GraphMonitorNode, quiet_s: float) -> None:
    """
    Spin until no message has moved for ``quiet_s`` (late diagnostics, last clouds) and the
    SfM has answered every keyframe. Live, the SfM may be several keyframes behind when the
    bag ends, and between two of its updates nothing moves for longer than ``quiet_s``.
    """
    start = time.monotonic()
    quiet_since, seen = start, monitor.total
    while time.monotonic() - start < DRAIN_LIMIT_S:
        quiet = time.monotonic() - quiet_since
        if quiet >= quiet_s and (not _sfm_behind(monitor) or quiet >= STALLED_S):
            return
        executor.spin_once(timeout_sec=0.02)
        if monitor.total != seen:
            quiet_since, seen = time.monotonic(), monitor.total


def _sfm_behind(monitor: GraphMonitorNode) -> bool:
    """Keyframes published that the SfM has neither answered with a path nor skipped (live)."""
    counts = monitor.counts
    values = monitor.diagnostics.get(SFM_STATUS, {}).get('values', {})
    try:
        skipped = int(values.get('keyframes_skipped', 0))
    except ValueError:
        skipped = 0
    answered = counts.get(KEYFRAME_PATH_TOPIC, 0)
    return counts.get(KEYFRAMES_TOPIC, 0) > answered + skipped and answered > 0


def node_report(node: Node) -> dict[str, Any]:
    report = getattr(node, 'report', None)
    return report() if callable(report) else {}
