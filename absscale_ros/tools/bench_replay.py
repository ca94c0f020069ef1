"""
``absscale bench replay``: frames per second of bag_replay in lossless step mode.

Two in-process nodes: bag_replay publishing serialized frames and step_sink deserializing and
acknowledging each one, so every frame makes the full round trip the graph will make.
"""
import argparse
from pathlib import Path
import tempfile
import time

import numpy as np

RAW_TYPE = 'sensor_msgs/msg/Image'
JPEG_TYPE = 'sensor_msgs/msg/CompressedImage'


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--frames', type=int, default=300, help='frames per bag')
    parser.add_argument('--size', default='1280x720', help='WxH of the synthetic frames')


def write_synthetic_bag(path: Path, kind: str, frames: int, size: tuple[int, int]) -> None:
    """Write ``frames`` textured 30 fps frames, JPEG CompressedImage or raw bgr8 Image."""
    from absscale_ros import bagio, conversions
    from rclpy.serialization import serialize_message
    rng = np.random.default_rng(0)
    w, h = size
    base = (rng.random((h // 8, w // 8, 3)) * 255).astype(np.uint8)
    base = np.kron(base, np.ones((8, 8, 1), np.uint8))
    with bagio.BagWriter(path) as writer:
        for i in range(frames):
            stamp = 1_000_000_000 + i * 33_333_333
            img = np.roll(base, i * 3, axis=1)
            if kind == 'jpeg':
                msg = conversions.bgr_to_compressed_msg(img, 'jpeg', 90, stamp, 'camera')
                writer.write('/camera/image_raw/compressed', JPEG_TYPE, stamp,
                             serialize_message(msg))
            else:
                msg = conversions.array_to_image_msg(img, 'bgr8', stamp, 'camera')
                writer.write('/camera/image_raw', RAW_TYPE, stamp, serialize_message(msg))


def measure_step_fps(bag: Path, topic: str, msgtype: str) -> tuple[float, int]:
    """Replay ``bag`` in step mode into a step_sink; return (frames/s, frames received)."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from absscale_ros.nodes.bag_replay import BagReplayNode
    from absscale_ros.nodes.step_sink import StepSinkNode
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        sink = StepSinkNode(context=context, parameter_overrides=[
            Parameter('topic', value=topic), Parameter('msgtype', value=msgtype)])
        replay = BagReplayNode(context=context, parameter_overrides=[
            Parameter('bag', value=str(bag)), Parameter('mode', value='step'),
            Parameter('expect_nodes', value='step_sink')])
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(sink)
        executor.add_node(replay)
        while replay.steps == 0:
            executor.spin_once(timeout_sec=0.05)
        t0, n0 = time.perf_counter(), sink.count
        while not replay.finished:
            executor.spin_once(timeout_sec=0.05)
        while sink.count < replay.steps and time.perf_counter() - t0 < 60:
            executor.spin_once(timeout_sec=0.05)
        fps = (sink.count - n0) / (time.perf_counter() - t0)
        return fps, sink.count
    finally:
        rclpy.try_shutdown(context=context)


def run(args: argparse.Namespace) -> int:
    w, h = (int(v) for v in args.size.split('x'))
    targets = {'jpeg': 300.0, 'raw': 100.0}
    with tempfile.TemporaryDirectory() as tmp:
        print(f'step-mode replay into an acknowledging subscriber, {args.frames} frames {w}x{h}')
        for kind, topic, msgtype in (('jpeg', '/camera/image_raw/compressed', JPEG_TYPE),
                                     ('raw', '/camera/image_raw', RAW_TYPE)):
            bag = Path(tmp) / f'{kind}.mcap'
            write_synthetic_bag(bag, kind, args.frames, (w, h))
            fps, got = measure_step_fps(bag, topic, msgtype)
            verdict = 'ok' if fps >= targets[kind] else 'BELOW TARGET'
            print(f'  {kind:5s} {fps:8.1f} frames/s  ({got}/{args.frames} received, '
                  f'target >= {targets[kind]:.0f})  {verdict}')
    return 0
