"""``absscale bag info BAG``: what a bag holds, without ROS."""
import argparse
import json

from absscale_ros import bagio, conversions

IMAGE_TYPES = ('sensor_msgs/msg/Image', 'sensor_msgs/msg/CompressedImage')


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('bag', help='rosbag2 folder or .mcap file')
    parser.add_argument('--json', action='store_true', help='print one JSON object')


def _image_summary(reader: bagio.BagReader, topic: str, msgtype: str) -> str:
    """Size and encoding of the first image on ``topic`` (decodes one message only)."""
    first = next(reader.messages([topic]), None)
    if first is None:
        return ''
    msg = reader.deserialize(first)
    if msgtype.endswith('CompressedImage'):
        size = bagio.image_size_of(bytes(conversions.compressed_bytes(msg)[:65536]))
        dims = f'{size[0]}x{size[1]}' if size else 'unknown size'
        return f'{dims} {conversions.compressed_format(msg)}'
    width, height, encoding = conversions.image_geometry(msg)
    return f'{width}x{height} {encoding}'


def info(path: str) -> dict[str, object]:
    """Return topics (type, count, rate, image size/encoding), start and duration."""
    with bagio.BagReader(path) as reader:
        duration_s = reader.duration_ns / 1e9
        topics = {}
        for topic, ti in reader.topics.items():
            entry: dict[str, object] = {'type': ti.msgtype, 'count': ti.count}
            if duration_s > 0 and ti.count > 1:
                entry['rate_hz'] = round((ti.count - 1) / duration_s, 2)
            if ti.msgtype in IMAGE_TYPES:
                entry['image'] = _image_summary(reader, topic, ti.msgtype)
            topics[topic] = entry
        return {'bag': str(path), 'start_s': reader.start_ns / 1e9, 'duration_s': duration_s,
                'messages': sum(t.count for t in reader.topics.values()), 'topics': topics}


def run(args: argparse.Namespace) -> int:
    summary = info(args.bag)
    if args.json:
        print(json.dumps(summary, indent=2))
        return 0
    print(f'bag:      {summary["bag"]}')
    print(f'duration: {summary["duration_s"]:.3f} s   messages: {summary["messages"]}')
    for topic, e in summary['topics'].items():  # type: ignore[attr-defined]
        rate = f'{e["rate_hz"]:.1f} Hz' if 'rate_hz' in e else ''
        print(f'  {topic:<36} {e["type"]:<34} {e["count"]:>7} {rate:>9}  {e.get("image", "")}')
    return 0
