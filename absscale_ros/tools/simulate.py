"""
``absscale simulate``: render a handheld video of a synthetic scene into a bag + gt.json.

The bag holds ``sensor_msgs/CompressedImage`` (JPEG, or PNG) on ``/camera/image_raw/compressed``
(or raw ``sensor_msgs/Image`` bgr8 on ``/camera/image_raw`` with ``--raw``) and
``sensor_msgs/CameraInfo`` on ``/camera/camera_info``, one pair per frame with equal stamps.
``BAG.gt.json`` beside it is the ground truth (docs/gt_schema.md).
"""
import argparse
import logging
from pathlib import Path
import time
from typing import Callable

import numpy as np
import numpy.typing as npt

from absscale_ros.core.errors import BagError

LOG = logging.getLogger('absscale.simulate')
COMPRESSED_TYPE = 'sensor_msgs/msg/CompressedImage'
RAW_TYPE = 'sensor_msgs/msg/Image'
INFO_TYPE = 'sensor_msgs/msg/CameraInfo'


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--scene', required=True, choices=('indoor_paper', 'outdoor_cube'))
    parser.add_argument('--seed', type=int, default=0, help='scene, camera and path variant')
    parser.add_argument('--out', required=True, type=Path,
                        help='bag to write: FILE.mcap, or a folder for a rosbag2 bag')
    parser.add_argument('--frames', type=int, default=300, help='frames at 30 fps (300 = 10 s)')
    parser.add_argument('--size', default='1280x720', help='WxH, e.g. 1920x1080')
    parser.add_argument('--raw', action='store_true', help='raw bgr8 Image instead of JPEG')
    parser.add_argument('--format', default='jpeg', choices=('jpeg', 'png'),
                        help='CompressedImage format')
    parser.add_argument('--quality', type=int, default=90, help='JPEG quality 1-100')
    parser.add_argument('--variant', nargs='*', default=[], metavar='KEY=VALUE',
                        help='override the seed\'s variant, e.g. target=a4 distractors=true')
    parser.add_argument('--image-topic', default=None,
                        help='default /camera/image_raw/compressed (/camera/image_raw if --raw)')
    parser.add_argument('--info-topic', default='/camera/camera_info')
    parser.add_argument('--frame-id', default='camera', help='header.frame_id of both topics')
    parser.add_argument('--no-pipeline', action='store_true',
                        help='finish each frame before rendering the next (same output)')
    parser.add_argument('--contact-sheet', type=Path, default=None, metavar='PNG',
                        help='also save 12 frames with their ground-truth vertices as a PNG')


def parse_size(text: str) -> tuple[int, int]:
    """'1280x720' -> (1280, 720); raises ValueError otherwise."""
    try:
        w, h = (int(v) for v in text.lower().split('x'))
    except ValueError:
        raise ValueError(f'--size must look like 1280x720, got {text!r}') from None
    return w, h


def parse_variant(items: list[str]) -> dict[str, object]:
    """['target=a4', 'distractors=true'] -> {'target': 'a4', 'distractors': True}."""
    out: dict[str, object] = {}
    for item in items:
        key, sep, value = item.partition('=')
        if not sep:
            raise ValueError(f'--variant items are KEY=VALUE, got {item!r}')
        low = value.lower()
        out[key] = True if low in ('true', '1', 'yes') else False if low in (
            'false', '0', 'no') else value
    return out


def gt_path(bag: Path) -> Path:
    """Ground truth beside the bag: ``bags/x.mcap`` -> ``bags/x.mcap.gt.json``."""
    return bag.with_name(bag.name + '.gt.json')


def make_serializer() -> Callable[[object, str], bytes]:
    """
    ``(msg, msgtype) -> CDR bytes`` with zeroed alignment padding.

    rclpy's serialize_message leaves CDR padding bytes uninitialised (they differ from run to
    run), so the bytes go once through rosbags' CDR codec, which writes zeros there: the same
    seed then gives the same bag, byte for byte.
    """
    from rclpy.serialization import serialize_message
    from rosbags.typesys import get_typestore, Stores
    store = get_typestore(Stores.ROS2_JAZZY)

    def serialize(msg: object, msgtype: str) -> bytes:
        raw = bytes(serialize_message(msg))
        return bytes(store.serialize_cdr(store.deserialize_cdr(raw, msgtype), msgtype))
    return serialize


def make_encoder(args: argparse.Namespace) -> tuple[str, str, Callable[..., bytes]]:
    """Topic, message type and ``(image_bgr, stamp_ns) -> CDR bytes`` for the chosen format."""
    from absscale_ros import conversions
    serialize = make_serializer()
    if args.raw:
        def encode(image: npt.NDArray[np.uint8], stamp_ns: int) -> bytes:
            msg = conversions.array_to_image_msg(image, 'bgr8', stamp_ns, args.frame_id)
            return serialize(msg, RAW_TYPE)
        return args.image_topic or '/camera/image_raw', RAW_TYPE, encode

    def encode_compressed(image: npt.NDArray[np.uint8], stamp_ns: int) -> bytes:
        msg = conversions.bgr_to_compressed_msg(image, args.format, args.quality, stamp_ns,
                                                args.frame_id)
        return serialize(msg, COMPRESSED_TYPE)
    return args.image_topic or '/camera/image_raw/compressed', COMPRESSED_TYPE, encode_compressed


def simulate(args: argparse.Namespace) -> dict[str, float]:
    """Write the bag and gt.json; returns timing figures (s, frames/s)."""
    import cv2

    from absscale_ros import bagio, conversions
    from absscale_ros.sim import contact, groundtruth, simulation
    width, height = parse_size(args.size)
    cfg = simulation.SimConfig(args.scene, args.seed, args.frames, width, height,
                               variant=parse_variant(args.variant))
    if args.out.exists():
        raise BagError(f'{args.out}: already exists; will not overwrite a bag')
    t0 = time.perf_counter()
    sim = simulation.Simulation(cfg)
    setup_s = time.perf_counter() - t0
    topic, msgtype, encode = make_encoder(args)
    serialize = make_serializer()
    gt = sim.header({'image_topic': topic, 'camera_info_topic': args.info_topic,
                     'image_format': 'raw' if args.raw else args.format,
                     'jpeg_quality': args.quality if not args.raw and args.format == 'jpeg'
                     else None, 'frame_id': args.frame_id})
    frames, thumbs = [], []
    every = max(1, cfg.frames // 12)
    centre = sim.scene.targets[0].vertices_world_m.mean(axis=0)
    t1, cpu1 = time.perf_counter(), time.process_time()
    with bagio.BagWriter(args.out) as writer:
        for f in sim.frames(encode=encode, pipelined=not args.no_pipeline):
            info = conversions.camera_model_to_info_msg(sim.camera, f.stamp_ns, args.frame_id)
            writer.write(args.info_topic, INFO_TYPE, f.stamp_ns, serialize(info, INFO_TYPE))
            writer.write(topic, msgtype, f.stamp_ns, f.data)
            frames.append(f.truth)
            if getattr(args, 'contact_sheet', None) and f.index % every == 0 \
                    and len(thumbs) < 12:
                thumbs.append(contact.thumbnail(f.image_bgr, f.truth, centre))
            if (f.index + 1) % 60 == 0:
                LOG.info('%d / %d frames', f.index + 1, cfg.frames)
    loop_s, loop_cpu_s = time.perf_counter() - t1, time.process_time() - cpu1
    gt['frames'] = frames
    groundtruth.save(gt, gt_path(args.out))
    if thumbs:
        variant = ', '.join(f'{k}={v}' for k, v in sim.scene.variant.items())
        title = f'{cfg.scene} seed {cfg.seed} ({variant}), {width}x{height}'
        cv2.imwrite(str(args.contact_sheet), contact.sheet(thumbs, 3, title),
                    [cv2.IMWRITE_PNG_COMPRESSION, 9])
    return {'setup_s': setup_s, 'loop_s': loop_s, 'fps': cfg.frames / loop_s,
            'loop_cpu_s': loop_cpu_s}


def run(args: argparse.Namespace) -> int:
    try:
        figures = simulate(args)
    except ValueError as err:  # bad --size / --variant / scene values: a usage error
        LOG.error('%s', err)
        return 2
    LOG.info('wrote %s and %s: %d frames in %.1f s (%.1f frames/s, setup %.1f s)', args.out,
             gt_path(args.out), args.frames, figures['loop_s'], figures['fps'],
             figures['setup_s'])
    return 0
