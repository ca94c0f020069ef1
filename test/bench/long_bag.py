"""
Make a long bag by replaying a bag's laps back to back, for the memory figure of issue #8.

``python test/bench/long_bag.py IN.mcap OUT.mcap --laps 10``: every lap is shifted by the
input's duration plus one frame period, in log time and in each message's header stamp (the
first field of Image, CompressedImage and CameraInfo), so the stream never goes back in time.
The camera jumps back to its start at each lap, which the SfM sees as a tracking loss and a
new map segment: the map and the clouds keep growing as in a long scan.

``python test/bench/long_bag.py --growth OUT/report.json``: the figure of the issue from an
``absscale run`` of such a bag: resident MB after the first minute of video (report.json's
``rss_mb`` samples are [wall s, frames replayed, MB]; 30 frames a second) and at the end.
"""
import argparse
import json
import struct
import sys

from absscale_ros import bagio


def shifted(data: bytes, shift_ns: int) -> bytes:
    """``data`` (CDR, a Header first) with its header stamp moved by ``shift_ns``."""
    stamp = bagio.header_stamp_ns(data)
    if stamp is None:
        return data
    fmt = '<iI' if data[1] in (1, 3) else '>iI'
    new = stamp + shift_ns
    return data[:4] + struct.pack(fmt, new // 1_000_000_000, new % 1_000_000_000) + data[12:]


def growth(report_path: str, fps: float = 30.0) -> dict[str, float]:
    """RSS (MB) at the first sample past one minute of video, at the end, and the growth."""
    samples = json.load(open(report_path))['rss_mb']
    first = next((s for s in samples if s[1] >= 60.0 * fps), samples[-1])
    peak = max(s[2] for s in samples if s[1] >= first[1])
    return {'video_s': samples[-1][1] / fps, 'after_first_minute_mb': first[2],
            'end_mb': samples[-1][2], 'peak_after_mb': peak, 'growth_mb': samples[-1][2] -
            first[2], 'peak_growth_mb': peak - first[2]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('bag_in', nargs='?')
    parser.add_argument('bag_out', nargs='?')
    parser.add_argument('--laps', type=int, default=10)
    parser.add_argument('--growth', metavar='REPORT', help='print the RSS growth of a run')
    args = parser.parse_args(argv)
    if args.growth:
        print(json.dumps(growth(args.growth), indent=1))
        return 0
    if not args.bag_out:
        parser.error('give BAG_IN and BAG_OUT (or --growth REPORT)')
    with bagio.BagReader(args.bag_in) as reader, bagio.BagWriter(args.bag_out) as writer:
        topics = reader.topics
        images = [t for t, i in topics.items() if i.msgtype.endswith('Image')]
        period = reader.duration_ns // max(1, topics[images[0]].count - 1) if images else 0
        lap_ns = reader.duration_ns + period
        for lap in range(args.laps):
            for msg in reader.messages():
                shift = lap * lap_ns
                writer.write(msg.topic, msg.msgtype, msg.stamp_ns + shift,
                             shifted(msg.data, shift))
            print(f'lap {lap + 1}/{args.laps}', file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
