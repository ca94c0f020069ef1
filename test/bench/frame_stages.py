"""
CPU time per frame of each stage of the frame nodes' work, on one thread, without DDS: what a
split run's frame process (or one process's main and decode threads) spends on a bag.

  python test/bench/frame_stages.py /tmp/lead/bags/outdoor_cube_60s.mcap --config outdoor_cube

Stages, in a frame's order: the bag message's deserialisation, the JPEG decode (frame_ingest's
worker), the Image message made of the frame, the detector (``detect.detect`` with its cube
tracker and sheet history, as in vertex_detector), its vertices message, the keyframe selector's
``measure`` and ``decide`` (with the target's area from those vertices). Per frame: thread CPU
(``time.thread_time``), so another job on the machine inflates it less than wall time would.
"""
import argparse
from dataclasses import fields, replace
import json
import time
from typing import Any

from absscale_ros import bagio, conversions, params
from absscale_ros.core import (cube_track, detect, detect_cube, detect_sheet, keyframe_geometry,
                               keyframes, sheet_track)
from absscale_ros.nodes import common
import cv2
import numpy as np


def _config(cls: type, values: dict[str, Any], prefix: str = '') -> Any:
    """``cls()`` with the fields ``values`` holds (``prefix.field`` names when prefixed)."""
    cfg = cls()
    found = {f.name: values[prefix + f.name] for f in fields(cfg) if prefix + f.name in values}
    return replace(cfg, **{k: tuple(v) if isinstance(getattr(cfg, k), tuple) else v
                           for k, v in found.items()})


class Stages:
    """Times the stages of one frame after another (``run``), per stage in ``cpu_s``."""

    def __init__(self, config: str) -> None:
        sections = params.load_yaml(params.find_config(config))
        vd, ks = (params.node_params(sections, n) for n in ('vertex_detector',
                                                            'keyframe_selector'))
        sheets = tuple(vd.get('auto_sheets', ('letter', 'a4')))
        self.detect_cfg = detect.DetectConfig(
            target=vd.get('target', 'auto'), auto_sheets=sheets,
            sheet=_config(detect_sheet.SheetConfig, vd, 'sheet.'),
            cube=_config(detect_cube.CubeConfig, vd, 'cube.'))
        self.tracker = cube_track.CubeTracker(self.detect_cfg.cube)
        self.history = sheet_track.SheetHistory()
        self.selector = keyframes.KeyframeSelector(_config(keyframes.KeyframeConfig, ks))
        self.cpu_s: dict[str, float] = {}
        self.frames = self.keyframes = 0

    def _timed(self, stage: str, fn: Any, *args: Any) -> Any:
        t0 = time.thread_time()
        out = fn(*args)
        self.cpu_s[stage] = self.cpu_s.get(stage, 0.0) + time.thread_time() - t0
        return out

    def run(self, reader: Any, raw: Any, camera: Any) -> None:
        msg = self._timed('deserialise', reader.deserialize, raw)
        image = self._timed('decode', conversions.compressed_msg_to_bgr, msg)
        frame = self._timed('image_message', conversions.array_to_image_msg, image, 'bgr8',
                            self.frames + 1, 'camera')
        image = conversions.image_msg_to_bgr(frame)
        found = self._timed('detect', detect.detect, image, self.detect_cfg, camera.K,
                            camera.dist, self.tracker, self.history)
        cloud = self._timed('vertices_message', lambda: conversions.array_to_cloud_msg(
            detect.vertices_array(found), self.frames + 1, 'camera'))
        measured = self._timed('select_measure', self.selector.measure, self.frames, image,
                               camera)
        decision = self._timed('select_decide', self._decide, measured, cloud, image.shape)
        self.frames += 1
        self.keyframes += decision.keyframe

    def _decide(self, measured: keyframes.Measured, cloud: Any,
                shape: tuple[int, ...]) -> keyframes.Decision:
        """As the selector node decides: on the largest target's area in its vertices."""
        pts = conversions.cloud_msg_to_array(cloud)
        area = keyframe_geometry.target_area_fraction(
            np.stack([pts['u'], pts['v']], axis=1), pts['object_id'], shape[1], shape[0]) \
            if len(pts) else 0.0
        return self.selector.decide(measured, area)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('bag')
    parser.add_argument('--config', required=True)
    parser.add_argument('--limit', type=int, default=0, help='frames at most (0: all)')
    args = parser.parse_args()
    cv2.setNumThreads(1)  # as in every process of a run
    common.keep_freed_memory()  # as there too (frame-sized buffers reused, not zeroed anew)
    stages, camera = Stages(args.config), None
    with bagio.open_bag(args.bag) as reader:
        for raw in reader.messages():
            if raw.msgtype.endswith('CameraInfo') and camera is None:
                camera = conversions.camera_info_to_model(reader.deserialize(raw))
            elif raw.msgtype.endswith('CompressedImage') and camera is not None:
                stages.run(reader, raw, camera)
                if stages.frames == args.limit:
                    break
    n = max(stages.frames, 1)
    print(json.dumps({'frames': stages.frames, 'keyframes': stages.keyframes,
                      'ms_per_frame': {k: round(1e3 * v / n, 3) for k, v in stages.cpu_s.items()},
                      'total_s': {k: round(v, 2) for k, v in stages.cpu_s.items()}}))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
