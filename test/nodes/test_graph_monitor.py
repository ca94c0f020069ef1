"""graph_monitor counts decoded frames from the acknowledgements, and receives them to record."""
from pathlib import Path

from absscale_ros import bagio
from absscale_ros.nodes.bag_replay import BagReplayNode
from absscale_ros.nodes.frame_ingest import FrameIngestNode
from absscale_ros.nodes.graph_monitor import GraphMonitorNode
from bagfactory import write_camera_bag
import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from ros_helpers import spin_until

FRAMES = '/absscale/frames'


@pytest.mark.parametrize('record', [False, True])
def test_frames_are_counted_and_only_a_recording_receives_them(context, tmp_path: Path,
                                                               record: bool) -> None:
    bag = tmp_path / 'cam.mcap'
    write_camera_bag(bag, frames=6)
    ingest = FrameIngestNode(context=context)
    monitor = GraphMonitorNode(context=context)
    monitor.discover()
    if record:
        monitor.record(str(tmp_path / 'rec.mcap'))
    replay = BagReplayNode(context=context, parameter_overrides=[
        Parameter('bag', value=str(bag)), Parameter('mode', value='step'),
        Parameter('expect_nodes', value='frame_ingest'),
        Parameter('observer', value=monitor.get_name()),
        Parameter('observer_images', value=record)])
    executor = SingleThreadedExecutor(context=context)
    for node in (ingest, monitor, replay):
        executor.add_node(node)
    assert spin_until(executor, lambda: replay.drained and monitor.counts.get(FRAMES) == 6,
                      timeout_s=20.0), monitor.counts
    spin_until(executor, lambda: False, timeout_s=0.3)  # nothing more arrives
    monitor.close()
    assert monitor.counts[FRAMES] == 6 and ingest.decoded == 6
    assert (FRAMES in monitor.announced) != record
    # Received frames are measured (320x240 bgr8: 230 kB each); announced ones are not.
    assert monitor.bytes.get(FRAMES, 0) > 6 * 320 * 240 * 3 if record else \
        FRAMES not in monitor.bytes
    if record:
        with bagio.BagReader(tmp_path / 'rec.mcap') as reader:
            assert reader.topics[FRAMES].count == 6
