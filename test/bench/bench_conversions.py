"""
Time message <-> numpy conversions (not a test): ``python test/bench/bench_conversions.py``.

Prints the median of several runs, in ms, for a 1280x720 bgr8 Image, a JPEG CompressedImage of
the same frame and a 100k-point xyz+rgb+id cloud, on rclpy messages and on rosbags-deserialized
ones.
"""
import argparse
import statistics
import time
from typing import Any, Callable

from absscale_ros import conversions
import numpy as np
from rclpy.serialization import serialize_message
from rosbags.typesys import get_typestore, Stores


def median_ms(func: Callable[[], Any], repeats: int) -> float:
    func()  # warm up (imports, allocator)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        func()
        times.append(time.perf_counter() - start)
    return 1e3 * statistics.median(times)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--repeats', type=int, default=20)
    args = parser.parse_args(argv)
    typestore = get_typestore(Stores.ROS2_JAZZY)
    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:720, 0:1280]
    frame = np.dstack([x % 256, y % 256, (x + y) % 256]).astype(np.uint8)
    frame ^= rng.integers(0, 16, size=frame.shape, dtype=np.uint8)  # some texture for JPEG
    image_msg = conversions.array_to_image_msg(frame, 'bgr8')
    jpeg_msg = conversions.bgr_to_compressed_msg(frame, 'jpeg', 90)
    points = rng.normal(size=(100_000, 3))
    colors = rng.integers(0, 256, size=(100_000, 3), dtype=np.uint8)
    ids = np.arange(100_000, dtype=np.int32)
    cloud_msg = conversions.xyz_rgb_to_cloud_msg(points, colors, extra={'vertex_id': ids})
    bag_image = typestore.deserialize_cdr(serialize_message(image_msg), 'sensor_msgs/msg/Image')
    bag_cloud = typestore.deserialize_cdr(serialize_message(cloud_msg),
                                          'sensor_msgs/msg/PointCloud2')
    cases = [
        ('Image bgr8 1280x720 encode', lambda: conversions.array_to_image_msg(frame, 'bgr8')),
        ('Image bgr8 1280x720 decode (array)', lambda: conversions.image_msg_to_array(image_msg)),
        ('Image bgr8 1280x720 decode (bgr)', lambda: conversions.image_msg_to_bgr(image_msg)),
        ('Image bgr8 1280x720 decode rosbags', lambda: conversions.image_msg_to_bgr(bag_image)),
        ('JPEG q90 1280x720 encode', lambda: conversions.bgr_to_compressed_msg(frame)),
        ('JPEG q90 1280x720 decode', lambda: conversions.compressed_msg_to_bgr(jpeg_msg)),
        ('cloud 100k xyz+rgb+id encode',
         lambda: conversions.xyz_rgb_to_cloud_msg(points, colors, extra={'vertex_id': ids})),
        ('cloud 100k decode', lambda: conversions.cloud_msg_to_array(cloud_msg)),
        ('cloud 100k decode rosbags', lambda: conversions.cloud_msg_to_array(bag_cloud)),
        ('cloud 100k decode skip_nans',
         lambda: conversions.cloud_msg_to_array(cloud_msg, skip_nans=True)),
    ]
    print(f'JPEG size {len(jpeg_msg.data) / 1e3:.0f} kB; median of {args.repeats} runs')
    for name, func in cases:
        print(f'{name:40s} {median_ms(func, args.repeats):8.3f} ms')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
