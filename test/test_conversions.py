"""Round trips between ROS Image/CompressedImage/Time messages and numpy (conversions)."""
from absscale_ros import conversions
from absscale_ros.core import errors
from conversions_helpers import READERS, via_cdr
import cv2
from hypothesis import given, settings, strategies as st
import numpy as np
import pytest
from sensor_msgs.msg import CompressedImage, Image

RNG_SEED = 7
# encoding -> (dtype, channels) as the tests expect them, written out independently of the module.
ENCODINGS = {
    'bgr8': (np.uint8, 3), 'rgb8': (np.uint8, 3), 'bgra8': (np.uint8, 4), 'rgba8': (np.uint8, 4),
    'bgr16': (np.uint16, 3), 'rgb16': (np.uint16, 3), 'mono8': (np.uint8, 1),
    'mono16': (np.uint16, 1), '8UC1': (np.uint8, 1), '8UC3': (np.uint8, 3),
    '16UC1': (np.uint16, 1), '32FC1': (np.float32, 1), 'bayer_rggb8': (np.uint8, 1),
    'bayer_bggr8': (np.uint8, 1), 'bayer_gbrg8': (np.uint8, 1), 'bayer_grbg8': (np.uint8, 1),
    'uyvy': (np.uint8, 2), 'yuv422': (np.uint8, 2), 'yuyv': (np.uint8, 2),
    'yuv422_yuy2': (np.uint8, 2),
}


def random_image(encoding: str, height: int, width: int, seed: int = RNG_SEED) -> np.ndarray:
    dtype, channels = ENCODINGS[encoding]
    shape = (height, width) + ((channels,) if channels > 1 else ())
    rng = np.random.default_rng(seed)
    if dtype == np.float32:
        return rng.normal(size=shape).astype(np.float32)
    return rng.integers(0, np.iinfo(dtype).max, size=shape, endpoint=True, dtype=dtype)


def hand_made_image(image: np.ndarray, encoding: str, pad_bytes: int = 0,
                    bigendian: bool = False) -> Image:
    """Build an Image the way a driver would, row by row, with padding after each row."""
    order = '>' if bigendian else '<'
    rows = [np.ascontiguousarray(row).astype(image.dtype.newbyteorder(order)).tobytes()
            + b'\xab' * pad_bytes for row in image]
    row_bytes = len(rows[0]) if rows else 0
    return Image(height=image.shape[0], width=image.shape[1], encoding=encoding,
                 is_bigendian=int(bigendian), step=row_bytes, data=b''.join(rows))


# ------------------------------------------------------------------------------------------
# Time
# ------------------------------------------------------------------------------------------

def test_stamp_round_trip_keeps_nanoseconds_and_negative_times() -> None:
    for ns in (0, 1, 999_999_999, 1_700_000_000_123_456_789, -1, -1_000_000_001):
        stamp = conversions.ns_to_stamp(ns)
        assert 0 <= stamp.nanosec < 1_000_000_000
        assert conversions.stamp_to_ns(stamp) == ns
        assert conversions.stamp_to_ns(via_cdr(stamp)) == ns


def test_stamp_known_value() -> None:
    stamp = conversions.ns_to_stamp(1_700_000_000_123_456_789)
    assert (stamp.sec, stamp.nanosec) == (1_700_000_000, 123_456_789)


def test_stamp_with_nanosec_overflow_is_rejected() -> None:
    stamp = conversions.ns_to_stamp(0)
    stamp.nanosec = 1_000_000_000
    with pytest.raises(errors.MessageError, match='1000000000'):
        conversions.stamp_to_ns(stamp)


def test_time_beyond_int32_seconds_is_rejected() -> None:
    with pytest.raises(ValueError, match='int32'):
        conversions.ns_to_stamp(2 ** 31 * 1_000_000_000)


# ------------------------------------------------------------------------------------------
# Image writers and readers
# ------------------------------------------------------------------------------------------

def test_bgr8_image_msg_has_unpadded_rows_and_header() -> None:
    image = np.arange(4 * 6 * 3, dtype=np.uint8).reshape(4, 6, 3)
    msg = conversions.array_to_image_msg(image, 'bgr8', stamp_ns=2_000_000_005, frame_id='cam')
    assert (msg.height, msg.width, msg.step, msg.encoding) == (4, 6, 18, 'bgr8')
    assert msg.is_bigendian == 0
    assert bytes(msg.data) == image.tobytes()
    assert msg.header.frame_id == 'cam'
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (2, 5)


def test_a_frame_is_copied_once_into_its_message() -> None:
    """A 1280x720 frame: one copy into the message (the setter of a message made without
    check_fields copies the data array again), and the same bytes on the wire."""
    import tracemalloc
    from rclpy.serialization import deserialize_message, serialize_message
    image = random_image('bgr8', 720, 1280)
    tracemalloc.start()
    msg = conversions.array_to_image_msg(image, 'bgr8', stamp_ns=5, frame_id='cam')
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert image.nbytes <= peak < 1.5 * image.nbytes
    plain = Image(height=720, width=1280, encoding='bgr8', step=3840)
    plain.header = msg.header
    plain.data = image.tobytes()
    # Compared after a round trip, not byte for byte: the CDR alignment padding after the
    # encoding string is not written by the serializer, so its bytes vary from call to call.
    assert deserialize_message(serialize_message(msg), Image) == plain


def test_mono16_is_written_little_endian() -> None:
    msg = conversions.array_to_image_msg(np.array([[0x0102, 0xA0B0]], np.uint16), 'mono16')
    assert bytes(msg.data) == b'\x02\x01\xb0\xa0'
    assert msg.step == 4
    swapped = conversions.array_to_image_msg(np.array([[0x0102, 0xA0B0]], '>u2'), 'mono16')
    assert bytes(swapped.data) == b'\x02\x01\xb0\xa0' and swapped.is_bigendian == 0


@pytest.mark.parametrize('reader', READERS)
@pytest.mark.parametrize('encoding', ENCODINGS)
def test_every_encoding_round_trips_through_rclpy_and_cdr(encoding: str, reader: str) -> None:
    image = random_image(encoding, 6, 10)
    msg = READERS[reader](conversions.array_to_image_msg(image, encoding, stamp_ns=42))
    decoded = conversions.image_msg_to_array(msg)
    assert decoded.dtype == image.dtype
    np.testing.assert_array_equal(decoded, image)
    assert conversions.stamp_to_ns(msg.header.stamp) == 42


def test_bgr8_decode_is_a_view_on_the_message_data() -> None:
    msg = conversions.array_to_image_msg(random_image('bgr8', 72, 128), 'bgr8')
    for decoded in (conversions.image_msg_to_array(msg), conversions.image_msg_to_bgr(msg)):
        assert np.shares_memory(decoded, np.frombuffer(msg.data, np.uint8))


def test_padded_rows_are_skipped_without_copying() -> None:
    image = random_image('rgb8', 5, 7)
    msg = hand_made_image(image, 'rgb8', pad_bytes=11)
    assert msg.step == 7 * 3 + 11
    decoded = conversions.image_msg_to_array(msg)
    np.testing.assert_array_equal(decoded, image)
    assert np.shares_memory(decoded, np.frombuffer(msg.data, np.uint8))
    np.testing.assert_array_equal(conversions.image_msg_to_bgr(msg), image[..., ::-1])


@pytest.mark.parametrize('reader', READERS)
def test_big_endian_mono16_is_decoded_to_native_values(reader: str) -> None:
    image = np.array([[1, 256, 65535], [258, 0, 4096]], np.uint16)
    msg = READERS[reader](hand_made_image(image, 'mono16', pad_bytes=2, bigendian=True))
    decoded = conversions.image_msg_to_array(msg)
    assert decoded.dtype == np.dtype(np.uint16)
    np.testing.assert_array_equal(decoded, image)


@settings(max_examples=60, deadline=None)
@given(encoding=st.sampled_from(sorted(ENCODINGS)), height=st.integers(1, 9),
       width=st.integers(1, 9), pad_bytes=st.integers(0, 9), bigendian=st.booleans(),
       seed=st.integers(0, 2 ** 16))
def test_any_shape_padding_and_byte_order_decodes(encoding: str, height: int, width: int,
                                                  pad_bytes: int, bigendian: bool,
                                                  seed: int) -> None:
    image = random_image(encoding, height, width, seed)
    msg = hand_made_image(image, encoding, pad_bytes, bigendian)
    for read in READERS.values():
        decoded = conversions.image_msg_to_array(read(msg))
        assert decoded.shape == image.shape
        np.testing.assert_array_equal(decoded, image)


# ------------------------------------------------------------------------------------------
# To BGR
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize('reader', READERS)
def test_colour_encodings_reorder_to_bgr(reader: str) -> None:
    bgr = random_image('bgr8', 4, 6)
    bgra = np.dstack([bgr, np.full(bgr.shape[:2], 200, np.uint8)])
    cases = {'bgr8': bgr, 'rgb8': bgr[..., ::-1], 'bgra8': bgra, 'rgba8': bgra[..., [2, 1, 0, 3]],
             '8UC3': bgr}
    for encoding, image in cases.items():
        msg = READERS[reader](conversions.array_to_image_msg(image, encoding))
        out = conversions.image_msg_to_bgr(msg)
        assert out.dtype == np.uint8 and out.flags.c_contiguous
        np.testing.assert_array_equal(out, bgr, err_msg=encoding)


def test_mono_encodings_become_grey_bgr_and_16_bit_is_scaled_over_full_range() -> None:
    # 65280 = 255 * 256 tells x 255 / 65535 (254) from a plain shift by 8 bits (255).
    mono16 = np.array([[0, 257, 65535, 257 * 100, 65280]], np.uint16)
    out = conversions.image_msg_to_bgr(conversions.array_to_image_msg(mono16, 'mono16'))
    np.testing.assert_array_equal(out, np.repeat([[[0], [1], [255], [100], [254]]], 3, axis=2))
    mono8 = np.array([[3, 250]], np.uint8)
    out = conversions.image_msg_to_bgr(conversions.array_to_image_msg(mono8, 'mono8'))
    np.testing.assert_array_equal(out, np.repeat(mono8[..., None], 3, axis=2))


def test_rgb16_is_scaled_and_reordered() -> None:
    rgb16 = np.array([[[65535, 0, 257 * 10]]], np.uint16)
    out = conversions.image_msg_to_bgr(conversions.array_to_image_msg(rgb16, 'rgb16'))
    np.testing.assert_array_equal(out, [[[10, 0, 255]]])


def mosaic(bgr: np.ndarray, pattern: str) -> np.ndarray:
    """Sample a BGR image with a 2x2 Bayer pattern such as 'rggb' (top-left first)."""
    channel = {'r': 2, 'g': 1, 'b': 0}
    raw = np.empty(bgr.shape[:2], np.uint8)
    for i, colour in enumerate(pattern):
        dy, dx = divmod(i, 2)
        raw[dy::2, dx::2] = bgr[dy::2, dx::2, channel[colour]]
    return raw


@pytest.mark.parametrize('pattern', ['rggb', 'bggr', 'gbrg', 'grbg'])
def test_bayer_is_demosaiced_with_the_right_pattern(pattern: str) -> None:
    # A flat colour with distinct R, G and B: any pattern mix-up swaps or blends channels.
    bgr = np.empty((8, 10, 3), np.uint8)
    bgr[:] = (20, 120, 230)
    msg = via_cdr(conversions.array_to_image_msg(mosaic(bgr, pattern), f'bayer_{pattern}8'))
    out = conversions.image_msg_to_bgr(msg)
    assert out.shape == (8, 10, 3)
    np.testing.assert_array_equal(out[2:-2, 2:-2], bgr[2:-2, 2:-2])


@pytest.mark.parametrize('encoding,luma_byte',
                         [('uyvy', 1), ('yuv422', 1), ('yuyv', 0), ('yuv422_yuy2', 0)])
def test_yuv422_byte_order_and_decode(encoding: str, luma_byte: int) -> None:
    # A grey ramp: luma changes along the row while chroma stays neutral (128).
    grey = np.repeat(np.repeat(np.arange(40, 200, 10, dtype=np.uint8)[None, :], 4, 0)[..., None],
                     3, axis=2)
    msg = conversions.array_to_image_msg(grey, encoding)
    packed = conversions.image_msg_to_array(msg)
    assert packed.shape == (4, 16, 2)
    assert np.all(np.abs(packed[..., 1 - luma_byte].astype(int) - 128) <= 1)
    assert np.all(np.diff(packed[0, :, luma_byte].astype(int)) > 0)
    for read in READERS.values():
        out = conversions.image_msg_to_bgr(read(msg))
        assert np.max(np.abs(out.astype(int) - grey)) <= 2


def test_yuv422_from_bgr_needs_even_width() -> None:
    with pytest.raises(ValueError, match='even width'):
        conversions.array_to_image_msg(np.zeros((2, 3, 3), np.uint8), 'uyvy')


def test_depth_image_cannot_become_bgr() -> None:
    msg = conversions.array_to_image_msg(np.ones((2, 2), np.float32), '32FC1')
    with pytest.raises(errors.MessageError, match='32FC1'):
        conversions.image_msg_to_bgr(msg)


# ------------------------------------------------------------------------------------------
# Malformed images
# ------------------------------------------------------------------------------------------

def test_step_smaller_than_a_row_is_rejected_with_numbers() -> None:
    msg = Image(height=2, width=4, encoding='bgr8', step=10, data=bytes(40))
    with pytest.raises(errors.MessageError, match=r'step 10 < width 4 x 3 .* = 12'):
        conversions.image_msg_to_array(msg)


@pytest.mark.parametrize('reader', READERS)
def test_short_data_is_rejected_with_numbers(reader: str) -> None:
    msg = READERS[reader](Image(height=3, width=4, encoding='mono16', step=8, data=bytes(20)))
    with pytest.raises(errors.MessageError, match=r'20 bytes < step 8 x height 3 = 24'):
        conversions.image_msg_to_bgr(msg)


def test_unknown_encoding_is_rejected_when_reading_and_writing() -> None:
    msg = Image(height=1, width=1, encoding='nv12', step=1, data=bytes(2))
    with pytest.raises(errors.MessageError, match="'nv12'"):
        conversions.image_msg_to_array(msg)
    with pytest.raises(errors.MessageError, match="'hsv8'"):
        conversions.array_to_image_msg(np.zeros((1, 1, 3), np.uint8), 'hsv8')


def test_array_that_does_not_fit_the_encoding_is_rejected() -> None:
    with pytest.raises(ValueError, match='uint16'):
        conversions.array_to_image_msg(np.zeros((2, 2), np.uint8), 'mono16')
    with pytest.raises(ValueError, match=r'\(2, 2\)'):
        conversions.array_to_image_msg(np.zeros((2, 2), np.uint8), 'bgr8')


# ------------------------------------------------------------------------------------------
# Compressed images
# ------------------------------------------------------------------------------------------

def smooth_bgr(height: int = 48, width: int = 64) -> np.ndarray:
    y, x = np.mgrid[0:height, 0:width]
    return np.dstack([x * 3, y * 4, (x + y) * 2]).astype(np.uint8)


@pytest.mark.parametrize('reader', READERS)
def test_jpeg_round_trip_with_transport_format_string(reader: str) -> None:
    image = smooth_bgr()
    msg = conversions.bgr_to_compressed_msg(image, 'jpeg', 95, stamp_ns=9, frame_id='cam')
    assert msg.format == 'bgr8; jpeg compressed bgr8'
    assert bytes(msg.data[:2]) == b'\xff\xd8'
    out = conversions.compressed_msg_to_bgr(READERS[reader](msg))
    assert out.shape == image.shape and out.dtype == np.uint8
    assert np.mean(np.abs(out.astype(int) - image)) < 3.0
    assert msg.header.frame_id == 'cam' and msg.header.stamp.nanosec == 9


@pytest.mark.parametrize('reader', READERS)
def test_png_round_trip_is_lossless_and_keeps_depth(reader: str) -> None:
    image = smooth_bgr()
    msg = conversions.bgr_to_compressed_msg(image, 'png')
    assert msg.format == 'bgr8; png compressed bgr8'
    np.testing.assert_array_equal(conversions.compressed_msg_to_bgr(READERS[reader](msg)), image)
    mono16 = (np.arange(12, dtype=np.uint16).reshape(3, 4) * 5000)
    msg16 = READERS[reader](conversions.bgr_to_compressed_msg(mono16, 'png'))
    assert msg16.format == 'mono16; png compressed mono16'
    decoded = conversions.compressed_msg_to_array(msg16)
    assert decoded.dtype == np.uint16
    np.testing.assert_array_equal(decoded, mono16)
    # compressed_msg_to_bgr always gives 8-bit BGR, even for a 16-bit grey PNG.
    bgr16 = conversions.compressed_msg_to_bgr(msg16)
    assert bgr16.dtype == np.uint8 and bgr16.shape == (3, 4, 3)
    np.testing.assert_array_equal(bgr16[..., 0], mono16 >> 8)
    mono8 = image[..., 1]
    decoded8 = conversions.compressed_msg_to_array(conversions.bgr_to_compressed_msg(mono8, 'png'))
    np.testing.assert_array_equal(decoded8, mono8)


@pytest.mark.parametrize('fmt', ['jpeg', 'png', 'bgr8; jpeg compressed bgr8',
                                 'rgb8; png compressed bgr8', 'mono8; jpeg compressed mono8',
                                 'PNG', ''])
def test_image_transport_format_strings_are_understood(fmt: str) -> None:
    image = smooth_bgr(16, 16)
    ext = '.png' if 'png' in fmt.lower() or not fmt else '.jpg'
    msg = CompressedImage(format=fmt, data=cv2.imencode(ext, image)[1].tobytes())
    assert conversions.compressed_msg_to_bgr(msg).shape == (16, 16, 3)


@pytest.mark.parametrize('fmt', ['theora', '16UC1; compressedDepth png'])
def test_unsupported_compressed_formats_are_rejected(fmt: str) -> None:
    msg = CompressedImage(format=fmt, data=b'\x89PNG')
    with pytest.raises(errors.MessageError, match='unsupported CompressedImage format'):
        conversions.compressed_msg_to_bgr(msg)


@pytest.mark.parametrize('reader', READERS)
def test_undecodable_jpeg_is_rejected(reader: str) -> None:
    msg = READERS[reader](CompressedImage(format='jpeg', data=b'\xff\xd8not a jpeg at all'))
    with pytest.raises(errors.MessageError, match='could not decode 19 bytes'):
        conversions.compressed_msg_to_bgr(msg)
    with pytest.raises(errors.MessageError, match='no data'):
        conversions.compressed_msg_to_array(CompressedImage(format='png'))


def test_bad_compression_arguments_are_rejected() -> None:
    image = smooth_bgr(8, 8)
    with pytest.raises(ValueError, match='quality'):
        conversions.bgr_to_compressed_msg(image, 'jpeg', quality=0)
    with pytest.raises(ValueError, match='webp'):
        conversions.bgr_to_compressed_msg(image, 'webp')
    with pytest.raises(ValueError, match='uint16'):
        conversions.bgr_to_compressed_msg(image[..., 0].astype(np.uint16), 'jpeg')


@pytest.mark.parametrize('fmt,kind', [('jpeg', 'jpeg'), ('JPG', 'jpeg'), ('png', 'png'), ('', ''),
                                      ('rgb8; jpeg compressed bgr8', 'jpeg'),
                                      ('mono16; png compressed mono16', 'png'),
                                      ('16UC1; compressedDepth png', 'compresseddepth'),
                                      ('theora', 'theora')])
def test_compressed_format_names_the_compression(fmt: str, kind: str) -> None:
    assert conversions.compressed_format(CompressedImage(format=fmt)) == kind


@pytest.mark.parametrize('reader', READERS)
def test_payload_and_geometry_helpers_do_not_decode(reader: str) -> None:
    jpeg = READERS[reader](conversions.bgr_to_compressed_msg(smooth_bgr(8, 8)))
    payload = conversions.compressed_bytes(jpeg)
    assert payload.dtype == np.uint8 and bytes(payload[:2]) == b'\xff\xd8'
    assert np.shares_memory(payload, np.frombuffer(jpeg.data, np.uint8))
    image = READERS[reader](conversions.array_to_image_msg(np.zeros((3, 5), np.uint16), 'mono16'))
    assert conversions.image_geometry(image) == (5, 3, 'mono16')
