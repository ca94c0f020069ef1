"""
Pipeline nodes of ``absscale run`` in processes of their own: one per node (``--processes``)
or groups of nodes (``--split``), on the runner's DDS domain. Instead of a fixed settle, a run
starts once every endpoint on either side is matched to all that discovery knows of
(``NodeProcesses.matched``; each node process answers with ``MatchAnswers``).
"""
import ctypes
import functools
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import threading
import time
from typing import Any, Callable

from absscale_ros import params
from absscale_ros.core.errors import AbsScaleError
from absscale_ros.nodes import common
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node

PR_SET_PDEATHSIG = 1  # linux/prctl.h
# A node process run by ``--processes`` (its own console-script main) finds the runner's folder
# here and answers ``NodeProcesses.matched`` under its node's name.
MATCH_DIR_ENV = 'ABSSCALE_MATCH_DIR'
STOP_TIMEOUT_S = 30.0  # for a node process to report and exit once interrupted
REPORT_POLL_S = 0.01  # how often ``stop`` looks for the reports
MATCH_PERIOD_S = 0.05  # how often a node process looks for the runner's question


class NodeProcesses:
    """
    Pipeline nodes in processes of their own on the runner's DDS domain: one per node
    (``--processes``) or several nodes in one (``groups``, see ``group_main``).
    """

    def __init__(self, config_path: Path, domain_id: int, live: bool,
                 groups: list[list[str]], own_main: bool = False,
                 nice: dict[str, int] | None = None) -> None:
        """:param nice: node name -> niceness added to the process that holds it (the largest
            of its nodes')."""
        from absscale_ros import graph
        self._dir = tempfile.TemporaryDirectory(prefix='absscale_nodes_')
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id))  # with run_graph's DDS profile
        sections = params.load_yaml(config_path)
        found = dict(graph.available_modules(sections))
        self.groups, self._own_main = groups, own_main
        self.names = [name for group in groups for name in group]
        self._procs: dict[str, subprocess.Popen] = {}
        self._expected: tuple[int, str] | None = None  # (version, counts) sent to the groups
        env[MATCH_DIR_ENV] = self._dir.name
        for group in groups:
            label = '+'.join(group)
            if own_main:  # --processes: each node as its own console script runs it
                name = group[0]
                args = ['--ros-args', '--params-file', str(config_path)]
                if name == 'scale' and graph.dense_enabled(sections):
                    args += ['-p', f'cloud_topic:={graph.SPARSE_METRIC_TOPIC}']
                if name == 'keyframe_selector' and 'vertex_detector' not in found:
                    args += ['-p', 'use_vertices:=false']
                if live:
                    args += ['-p', 'qos:=sensor_data']
                code = f'from {found[name]} import main; main()'
            else:
                args = [str(config_path), ','.join(group), 'live' if live else 'offline',
                        self._dir.name]
                code = 'from absscale_ros.node_processes import group_main; group_main()'
            # Its log goes to a file: a pipe nobody reads during a long run would fill and
            # stop the node.
            with open(Path(self._dir.name) / f'{label}.log', 'wb') as log:
                self._procs[label] = subprocess.Popen(
                    [sys.executable, '-c', code, *args],
                    env=dict(env, ABSSCALE_REPORT=str(Path(self._dir.name) / f'{label}.json')),
                    stdout=subprocess.DEVNULL, stderr=log, preexec_fn=functools.partial(
                        _start_child, max((nice or {}).get(name, 0) for name in group)))
        self._reports: dict[str, Any] | None = None
        self._reaper = threading.Thread(target=self._reap, name='node_reaper')
        self._after_reap: list[Callable[[], None]] = []
        self._reap_lock, self._reaped = threading.Lock(), False
        self.cpu_s: dict[str, float | None] = {}  # CPU time of each node process

    def matched(self, local: list[Node]) -> bool:
        """
        Whether every endpoint of ``local`` (this process's nodes) and of the node groups is
        matched to every peer discovery knows of: a message sent before its reader matched
        would be lost. The groups are told the counts this process sees and answer.
        """
        for label, proc in self._procs.items():
            if proc.poll() is not None:  # it died starting: its reason, not a silent wait
                raise AbsScaleError(f'node process {label} exited with {proc.returncode}: '
                                    f'{self._log(label)[-1000:]}')
        counts = _endpoint_counts(local[0])
        if self._expected is None or self._expected[1] != counts:
            version = 1 if self._expected is None else self._expected[0] + 1
            self._expected = (version, counts)
            tmp = Path(self._dir.name) / 'expect.tmp'
            tmp.write_text(json.dumps({'version': version, **json.loads(counts)}))
            tmp.replace(Path(self._dir.name) / 'expect.json')  # never read half written
            return False
        answers = [_read(Path(self._dir.name) / f'{"+".join(g)}.ready') for g in self.groups]
        answers = [json.loads(a) for a in answers if a]
        if len(answers) < len(self.groups) or \
                any(a['version'] != self._expected[0] for a in answers):
            return False
        # Discovery here must know every endpoint there is: one it has not seen yet would
        # not be counted, and a publisher here would seem matched without it.
        known = json.loads(counts)
        for side in ('pubs', 'subs'):
            needed = _own_endpoints(local)[side]
            for a in answers:
                for topic, n in a[side].items():
                    needed[topic] = needed.get(topic, 0) + n
            if any(known[side].get(t, 0) < n for t, n in needed.items()):
                return False
        return not _unmatched(local, known)

    def _log(self, label: str) -> str:
        try:
            return (Path(self._dir.name) / f'{label}.log').read_bytes().decode(
                errors='replace').strip()
        except OSError:
            return ''

    def stop(self) -> dict[str, Any]:
        """
        Interrupt every node and collect the reports they write as they stop. The processes
        are reaped on a thread of their own (``reaped``): what is left of a node process once
        its report is written (its nodes' and DDS's teardown, ~0.5 s at a run's end) need not
        delay the run's outputs. Not a daemon: the interpreter waits for it before it exits.
        """
        if self._reports is not None:
            return self._reports
        for proc in self._procs.values():
            proc.send_signal(signal.SIGINT)
        try:
            reports: dict[str, Any] = {}
            deadline = time.monotonic() + STOP_TIMEOUT_S
            for group in self.groups:
                label = '+'.join(group)
                proc, path = self._procs[label], Path(self._dir.name) / f'{label}.json'
                # Its report, or its exit (one without a report); killed if it has neither in time.
                while not path.exists() and proc.poll() is None and time.monotonic() < deadline:
                    time.sleep(REPORT_POLL_S)
                if not path.exists() and proc.poll() is None:
                    proc.kill()
                    proc.wait()
                found = json.loads(path.read_text()) if path.exists() else {}
                if self._own_main:
                    found = {label: found} if found else {}
                # A process that wrote a report without this node's entry may still be running.
                status = 'no entry in its report' if proc.poll() is None else \
                    f'exit {proc.returncode}'
                for name in group:
                    reports[name] = found.get(name) or {
                        'error': f'{status}: {self._log(label)[-500:]}'}
                    cpu = reports[name].pop('process_cpu_s', None)
                    if cpu is not None:
                        self.cpu_s[label] = cpu
        finally:  # reaped even when this fails: else the domain lease is never released
            if self._reaper.ident is None:
                self._reaper.start()
        self._reports = reports
        return reports

    def reaped(self, then: Callable[[], None]) -> None:
        """Call ``then`` once every node process has exited (on the reaping thread)."""
        with self._reap_lock:
            if not self._reaped:
                self._after_reap.append(then)
                return
        then()

    def _reap(self) -> None:
        deadline = time.monotonic() + STOP_TIMEOUT_S
        for proc in self._procs.values():
            try:
                proc.wait(timeout=max(deadline - time.monotonic(), 0.0))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        self._dir.cleanup()
        with self._reap_lock:
            self._reaped = True
        for then in self._after_reap:
            then()


def _read(path: Path) -> str | None:
    try:
        return path.read_text()
    except OSError:
        return None


# ROS's own topics carry nothing a run needs.
UNCHECKED_TOPICS = ('/rosout', '/parameter_events')


def _endpoint_counts(node: Node) -> str:
    """JSON {'pubs': {topic: publishers}, 'subs': {topic: subscribers}} discovery knows."""
    topics = [t for t, _ in node.get_topic_names_and_types() if t not in UNCHECKED_TOPICS]
    return json.dumps({'pubs': {t: node.count_publishers(t) for t in topics},
                       'subs': {t: node.count_subscribers(t) for t in topics}}, sort_keys=True)


def _own_endpoints(nodes: list[Node]) -> dict[str, dict[str, int]]:
    """{'pubs': {topic: publishers}, 'subs': {topic: subscriptions}} of ``nodes``."""
    out: dict[str, dict[str, int]] = {'pubs': {}, 'subs': {}}
    for node in nodes:
        for side, endpoints in (('pubs', node.publishers), ('subs', node.subscriptions)):
            for e in endpoints:
                if e.topic_name not in UNCHECKED_TOPICS:
                    out[side][e.topic_name] = out[side].get(e.topic_name, 0) + 1
    return out


def _unmatched(nodes: list[Node], counts: dict[str, dict[str, int]]) -> list[str]:
    """The topics of ``nodes`` whose publishers or subscriptions matched fewer peers than
    ``counts`` (from ``_endpoint_counts``) says exist."""
    out = []
    for node in nodes:
        for pub in node.publishers:
            if pub.get_subscription_count() < counts['subs'].get(pub.topic_name, 0):
                out.append(f'{node.get_name()} -> {pub.topic_name}')
        for sub in node.subscriptions:
            if sub.get_publisher_count() < counts['pubs'].get(sub.topic_name, 0):
                out.append(f'{node.get_name()} <- {sub.topic_name}')
    return out


class MatchAnswers:
    """
    In a node process: answers the runner's ``NodeProcesses.matched`` once every endpoint of
    ``nodes`` is matched to as many peers as the runner's discovery counts (its question,
    ``expect.json`` in ``folder``), with the endpoints they own (``LABEL.ready``).
    """

    def __init__(self, folder: Path, label: str, nodes: list[Node]) -> None:
        self._folder, self._label, self._nodes = folder, label, nodes
        self._answered: str | None = None
        self._checked = -MATCH_PERIOD_S

    def poll(self) -> None:
        """Answer a new question if it can be (cheap enough to call after every callback)."""
        now = time.monotonic()
        if now - self._checked < MATCH_PERIOD_S:
            return
        self._checked = now
        expect = _read(self._folder / 'expect.json')
        if not expect or expect == self._answered:
            return
        counts = json.loads(expect)
        if _unmatched(self._nodes, counts):
            return
        self._answered = expect
        own = _own_endpoints(self._nodes)
        tmp = self._folder / f'{self._label}.ready.tmp'
        tmp.write_text(json.dumps({'version': counts['version'], **own}))
        tmp.replace(self._folder / f'{self._label}.ready')  # never read half written


def group_main() -> None:
    """
    A node process of a split run holding several pipeline nodes, on one executor.

    Arguments: config path, node names (comma-separated), ``live`` or ``offline``, and the
    runner's folder, where it answers ``NodeProcesses.matched`` and leaves its reports.
    """
    from absscale_ros import graph
    config, names, live, folder = sys.argv[1], sys.argv[2].split(','), sys.argv[3], sys.argv[4]
    common.keep_freed_memory()
    common.one_opencv_thread()  # a split run's process: the others use the other core
    context = rclpy.Context()
    rclpy.init(context=context, args=[])  # ROS_DOMAIN_ID from the runner
    nodes = graph.start_nodes(context, params.load_yaml(Path(config)), live == 'live', names,
                              runner=False)
    executor = common.single_threaded_executor(context)
    for node in nodes.values():
        executor.add_node(node)
    answers = MatchAnswers(Path(folder), '+'.join(names), list(nodes.values()))
    try:
        while context.ok():
            executor.spin_once(timeout_sec=0.02)
            answers.poll()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        reports = {name: graph.node_report(node) for name, node in nodes.items()}
        reports[names[0]]['process_cpu_s'] = round(time.process_time(), 2)
        common.write_whole(os.environ['ABSSCALE_REPORT'], json.dumps(reports, default=str))
        executor.shutdown()
        for node in nodes.values():
            node.destroy_node()
        rclpy.try_shutdown(context=context)


def _start_child(nice: int) -> None:
    """
    In a node process before it starts: end it when the runner dies, and add ``nice`` to its
    niceness (``graph.SPLIT_NICE``). A runner killed by SIGTERM or SIGKILL runs no cleanup,
    and its nodes would go on replaying into nothing.
    SIGINT, which ``stop`` sends, is reset to its default: a runner started in the background
    by a non-interactive shell (``absscale run ... &`` in a script) ignores it, the ignoring is
    inherited, and its node processes then sat out the 30 s ``stop`` gives them, were killed
    and left no reports (a split run of each sample said no scale, twice in two runs).
    """
    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    if nice:
        os.nice(nice)
