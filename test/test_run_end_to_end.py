"""`absscale run` over a real bag: every node runs, outputs and the recording are written."""
import json
from pathlib import Path
import subprocess
import sys

from absscale_ros import bagio
from bagfactory import write_camera_bag


def test_run_writes_report_picture_and_recording(tmp_path: Path) -> None:
    bag = tmp_path / 'cam.mcap'
    write_camera_bag(bag, frames=12, size=(640, 360))
    out, rec = tmp_path / 'out', tmp_path / 'rec.mcap'
    done = subprocess.run([sys.executable, '-m', 'absscale_ros.cli', 'run', str(bag),
                           '--config', 'indoor_paper', '--out', str(out), '--record', str(rec)],
                          capture_output=True, text=True, timeout=300)
    # Random frames hold no calibration object: the run works but must claim no scale.
    assert done.returncode == 1, done.stderr[-3000:]
    assert done.stderr.strip().splitlines()[-1].startswith('absscale run: no metric scale')
    report = json.loads((out / 'report.json').read_text())
    assert report['replay']['steps'] == 12 and report['replay']['step_timeouts'] == 0
    assert report['messages_per_topic']['/camera/image_raw/compressed'] == 12
    for node in ('frame_ingest', 'vertex_detector', 'keyframe_selector'):
        assert node in report['nodes'], sorted(report['nodes'])
    assert report['messages_per_topic'].get('/absscale/frames') == 12
    assert len(report['detections']) == 12  # one vertices cloud per frame, empty or not
    assert (out / 'run.png').stat().st_size > 10_000
    with bagio.BagReader(rec) as reader:
        topics = reader.topics
    assert topics['/absscale/frames'].count == 12
    assert '/camera/image_raw/compressed' not in topics  # the bag's own topics are not re-recorded
